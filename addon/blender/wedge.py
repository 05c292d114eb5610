"""The Blender half of `tearcloth farm`: list a file's Tear Cloth objects, and write one wedge
variation of a .blend (settings overrides applied) for ``tearcloth bake`` to bake.

What this file owns: ``inspect`` (which objects of each file can be baked, read before any farm
task starts) and ``write_variation`` (open the user's file, set the overridden properties of one
object, save a copy). The bpy-free side (``tearcloth.farm``) runs both as subprocesses:

    python -m tearcloth.blender.wedge inspect FILE.blend...            -> JSON on stdout
    python -m tearcloth.blender.wedge variation SRC OUT OBJECT JSON [--keep-engine]

Every file is opened with Blender's script auto-execution OFF, whatever the file or the user's
preferences ask (a farm never runs code embedded in a scene): the preference is forced off and
the load is asked not to run scripts. Values arrive in SI, keyed ``group.name`` of the settings
table; scene lengths become Blender units here (``convert.length_from_si``), enumerations upper
case (Blender's convention). Unless ``--keep-engine``, the copy renders with Workbench, so a
contact sheet costs seconds per variation.
"""
from __future__ import annotations

import json
import sys
import warnings

import bpy

from .. import settings as table
from . import convert, modifier, register


def _open(path: str) -> None:
    bpy.context.preferences.filepaths.use_scripts_auto_execute = False
    bpy.ops.wm.open_mainfile(filepath=path, load_ui=False, use_scripts=False)
    # a file cannot switch the preference on, but a handler of an add-on could: check, not hope
    if bpy.context.preferences.filepaths.use_scripts_auto_execute:
        raise RuntimeError("script auto-execution was switched on while opening the file")


def inspect(paths: list[str]) -> dict:
    """{path: {"objects": [Tear Cloth object names], "frames": [start, end], "scene": name,
    "camera": bool, "auto_execute": bool}} for each file (the last: the preference after load)."""
    register()
    out = {}
    for path in paths:
        _open(path)
        scene = bpy.context.scene
        out[path] = {"objects": sorted(o.name for o in scene.objects if modifier.is_enabled(o)),
                     "frames": [scene.frame_start, scene.frame_end], "scene": scene.name,
                     "camera": scene.camera is not None,
                     "auto_execute": bool(bpy.context.preferences.filepaths.use_scripts_auto_execute)}
    return out


def _blender_value(row, value, scene):
    if row.kind == "enum":
        return value.upper()
    if row.is_scene_length:
        return convert.length_from_si(scene, value)
    return value


def write_variation(source: str, output: str, object_name: str, overrides: dict, workbench: bool = True) -> dict:
    """Open ``source``, set ``overrides`` ({"group.name": SI value}) on ``object_name``'s Tear
    Cloth settings, save the result as ``output``. Returns what was set, as Blender stores it."""
    register()
    _open(source)
    scene = bpy.context.scene
    obj = bpy.data.objects.get(object_name)
    if obj is None or not modifier.is_enabled(obj):
        raise ValueError(f"{source}: {object_name!r} is not a Tear Cloth object")
    stored = {}
    for key, value in overrides.items():
        group, name = key.split(".", 1)
        row = table.setting(group, name)
        row.check(value, object_name)
        owner = obj.tearcloth
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # '//' paths on string properties
            setattr(owner, row.blender_name, _blender_value(row, value, scene))
        stored[key] = getattr(owner, row.blender_name)
    if workbench:
        scene.render.engine = "BLENDER_WORKBENCH"
    bpy.context.preferences.filepaths.save_version = 0
    bpy.ops.wm.save_as_mainfile(filepath=output, relative_remap=True, copy=True)
    return {"set": stored, "auto_execute": bool(bpy.context.preferences.filepaths.use_scripts_auto_execute)}


def main(argv: list[str]) -> int:
    if argv and argv[0] == "inspect":
        print(json.dumps(inspect(argv[1:])))
        return 0
    if argv and argv[0] == "variation" and len(argv) in (5, 6):
        _, source, output, name, overrides, *rest = argv
        print(json.dumps(write_variation(source, output, name, json.loads(overrides),
                                         workbench=rest != ["--keep-engine"])))
        return 0
    print("usage: python -m tearcloth.blender.wedge inspect FILE... | variation SRC OUT OBJECT JSON [--keep-engine]",
          file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
