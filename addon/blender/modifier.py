"""The "Tear Cloth" entry in the modifier stack, and where an object's cache lives on disk.

The modifier strategy (one modifier, its place kept for good)
--------------------------------------------------------------
Enabling Tear Cloth adds Blender's STOCK Mesh Sequence Cache (MSC) modifier named "Tear Cloth".
Before a bake it has no cache file, and an MSC without a cache file passes its input mesh through
unchanged: the object shows its rest mesh and every modifier above and below works as before.
A bake attaches the baked USD root (``//tearcloth_cache/<blend>/<object>.usda``, relative
to the .blend; see ``cache_path``)
to that same modifier, so the stack order the user chose never changes, and the result plays
back and renders with stock Blender alone (no add-on, no Python) on any machine, a render farm
node included. Freeing the bake detaches the cache again. Like Blender's own Cloth modifier, the
simulation starts from the mesh as evaluated by the modifiers ABOVE "Tear Cloth"; modifiers below
act on the torn result every frame (Solidify, Subdivision Surface, ...). The baked mesh carries
positions, faces, the active UV map under its own name (so a material's UV Map node finds it) and
velocities (for motion blur);
vertex groups are not in the cache, so modifiers below cannot use them.

A Geometry Nodes pass-through swapped for the MSC at bake time was the alternative; it would need
a node group in every file and a swap that moves the modifier's identity under the user.

This file owns: finding/adding/removing that modifier, the cache path of an object, and
attaching/detaching the cache file datablock.
"""
from __future__ import annotations

import hashlib
import os
import re
import uuid

import bpy

from .. import cache, settings
from .report import BakeError

MODIFIER_NAME = "Tear Cloth"
MODIFIER_TYPE = "MESH_SEQUENCE_CACHE"
DEFAULT_CACHE_FOLDER = settings.default("cache", "cache_folder")
# What the MSC reads from our USD: positions, faces, UVs, colour attributes (without COLOR the
# reader leaves them at white) and the other attributes ('velocity', the user's, torn/warp).
READ_DATA = {"VERT", "POLY", "UV", "COLOR", "ATTRIBUTES"}


def read_data(md) -> set:
    """READ_DATA as far as this Blender offers it: 4.2 LTS's modifier has no 'ATTRIBUTES' yet
    (bpy 4.2.23 reads the 'velocity' attribute all the same: tests/test_cache.py)."""
    offered = {item.identifier for item in md.bl_rna.properties["read_data"].enum_items}
    return READ_DATA & offered


def find_modifier(obj):
    """The object's "Tear Cloth" modifier, or None."""
    if obj is None or not hasattr(obj, "modifiers"):
        return None
    md = obj.modifiers.get(MODIFIER_NAME)
    return md if md is not None and md.type == MODIFIER_TYPE else None


def is_enabled(obj) -> bool:
    return find_modifier(obj) is not None


def add_modifier(obj):
    md = find_modifier(obj)
    if md is None:
        md = obj.modifiers.new(MODIFIER_NAME, MODIFIER_TYPE)
        md.read_data = read_data(md)
    return md


def modifier_index(obj, md) -> int:
    return list(obj.modifiers).index(md)


def prim_name_for(object_name: str) -> str:
    """A USD identifier (and file name) for an object. Names that are not identifiers already get
    a short hash of the real name, so 'Cloth.001' and 'Cloth_001' never share a cache."""
    safe = re.sub(r"[^A-Za-z0-9_]", "_", object_name)
    if not safe or safe[0].isdigit():
        safe = "_" + safe
    if safe != object_name:
        safe += "_" + hashlib.sha1(object_name.encode("utf-8")).hexdigest()[:6]
    return safe


def cache_folder(settings) -> str:
    """The cache folder as the user set it (``//`` = next to the .blend)."""
    return settings.cache_folder or DEFAULT_CACHE_FOLDER


# The custom property that holds an object's persistent id (copied with the object into other
# files, kept through renames; a new object has none until its first bake).
ID_PROPERTY = "tearcloth_id"


def object_id(obj) -> str:
    """The object's persistent id, or '' before its first bake."""
    value = obj.get(ID_PROPERTY) if hasattr(obj, "get") else None
    return value if isinstance(value, str) else ""


def _recorded(path: str) -> dict | None:
    """The owner a cache at ``path`` records (name and ``owner`` fields), or None."""
    return cache.owner_of(path)


def players(path: str, but=None) -> list:
    """The objects of this file (but ``but``) whose "Tear Cloth" modifier plays the cache root
    ``path``: a duplicate's modifier plays its original's bake until it bakes its own."""
    path = os.path.normcase(os.path.abspath(path))
    return [o for o in bpy.data.objects
            if o is not but and (a := attached_path(o)) is not None and os.path.normcase(a) == path]


def claim_id(obj, fingerprint: str | None = None) -> str:
    """Make sure the object has a persistent id of its own, and return it.

    An object without one adopts the id its cache recorded when that cache was baked for an
    object of its name and that id is not another object's in this file (the bake ran, the file
    was not saved after it) and, when ``fingerprint`` is given, for the same rest mesh;
    otherwise it gets a new id. An object that shares its id with
    another (Duplicate copies custom properties) keeps it only if its cache was baked for it and
    no object of that id plays that cache: a duplicate renamed to the name its original was baked
    under (the original renamed away, still playing the bake) would otherwise bake over it."""
    current = object_id(obj)
    taken = {object_id(o) for o in bpy.data.objects if o is not obj} - {""}
    if current and current not in taken:
        return current
    recorded = _recorded(_plain_path(obj))
    same_mesh = recorded is not None and (not fingerprint or not recorded.get("fingerprint")
                                          or recorded["fingerprint"] == fingerprint)
    # ... and by this file: another .blend of the same name whose cache folder is the same absolute
    # one (or any unsaved session: all are "untitled") bakes the same plain path, and adopting its id
    # made this object bake over that file's frames. A folder beside the .blend ("//...") is this
    # file's alone, even where it was copied with the file from another that still exists; a bake
    # recorded for a file that is no longer there is this one's, moved.
    typed = cache_folder(obj.tearcloth)
    beside = typed.startswith("//") or not os.path.isabs(os.path.expanduser(typed))  # "//x", "x", "./x" (_folder)
    this_file = bool(bpy.data.filepath) and (beside or not baked_by_another_file(recorded))
    if recorded is not None and recorded["object"] == obj.name and same_mesh and this_file:
        theirs = recorded.get("object_id", "")
        shown = current in taken and any(object_id(o) == current for o in players(_plain_path(obj), obj))
        if theirs and ((theirs == current and not shown) or (not current and theirs not in taken)):
            obj[ID_PROPERTY] = theirs
            return theirs
    new = uuid.uuid4().hex[:12]
    obj[ID_PROPERTY] = new
    return new


def _folder(obj) -> str:
    typed = cache_folder(obj.tearcloth)
    # "~" is the user's home (bpy.path.abspath leaves it as it is: a folder named "~" in the working
    # directory); a relative folder without "//" ("cache", "./cache") is taken beside the .blend,
    # like "//cache": relative to the working directory of whichever process baked, it landed
    # wherever Blender was started from, and its walk up to "" gave a garbled message
    folder = os.path.expanduser(typed)
    if not folder.startswith("//") and not os.path.isabs(folder):
        folder = "//" + os.path.normpath(folder)
    if folder.startswith("//") and not bpy.data.filepath:
        raise BakeError(
            f"the cache folder {typed!r} is relative to the .blend file, which is not saved yet: "
            "save the file first or choose an absolute cache folder (Physics > Tear Cloth > Cache)"
        )
    blend = bpy.path.display_name_from_filepath(bpy.data.filepath) or "untitled"
    return os.path.join(os.path.normpath(bpy.path.abspath(folder)), blend)


def _plain_path(obj) -> str:
    return os.path.join(_folder(obj), prim_name_for(obj.name) + ".usda")


def cache_path(obj) -> str:
    """Absolute path of the object's cache root. BakeError if it cannot be resolved.

    ``<cache folder>/<.blend name>/<object>.usda``: the .blend's name keeps two files in one
    folder (with objects of the same names, or one a copy of the other) apart. When that file
    belongs to another object (its recorded persistent id is not this object's: the object
    that baked it was renamed and this one took its name), this object's cache is
    ``<object>-<id>.usda`` instead, so the two never share a file."""
    plain = _plain_path(obj)
    ident = object_id(obj)
    recorded = _recorded(plain) if ident else None
    if recorded is not None and recorded.get("object_id") and recorded["object_id"] != ident:
        return os.path.join(os.path.dirname(plain), f"{prim_name_for(obj.name)}-{ident}.usda")
    return plain


def stored_path(path: str) -> str:
    """The path as the .blend should store it: relative ('//...') when the file is saved and the
    cache is on the same drive, so the .blend and its cache folder can move together."""
    if bpy.data.filepath:
        try:
            return bpy.path.relpath(path)
        except ValueError:  # another drive on Windows
            return path
    return path


def baked_by_another_file(recorded: dict | None) -> str:
    """The .blend a cache's owner record names when it is another file that still exists (this
    file a copy of it, or the object appended from it), else ''."""
    blend = (recorded or {}).get("blend") or ""
    return blend if blend and os.path.isfile(blend) and not same_file(blend, bpy.data.filepath or "") else ""


def same_file(a: str, b: str) -> bool:
    """Whether two paths (a may be Blender-relative, '//...') name one file."""
    return os.path.normcase(os.path.abspath(bpy.path.abspath(a))) == os.path.normcase(os.path.abspath(b))


def attached_path(obj) -> str | None:
    """Absolute path of the cache the modifier plays, or None."""
    return attached_path_of(find_modifier(obj))


def attached_path_of(md) -> str | None:
    """Absolute path of the cache a Mesh Sequence Cache modifier ``md`` plays, or None."""
    if md is None or md.cache_file is None:
        return None
    return os.path.abspath(bpy.path.abspath(md.cache_file.filepath))


def bake_played_by(md) -> tuple[str, dict] | None:
    """(path, recorded owner) of the Tear Cloth bake a modifier plays, whatever its name (a
    renamed "Tear Cloth", or a copy of it); None for another modifier or cache."""
    path = attached_path_of(md) if md.type == MODIFIER_TYPE else None
    owner = _recorded(path) if path is not None else None
    return (path, owner) if owner is not None else None


def attach_cache(obj, path: str, prim_name: str) -> None:
    """Point the object's "Tear Cloth" modifier at a cache root (adding the cache file datablock
    if needed, reloading it if it exists so frames baked since it was opened show up)."""
    md = find_modifier(obj)
    if md is None:
        raise BakeError(f"{obj.name!r} has no {MODIFIER_NAME!r} modifier; enable Tear Cloth again")
    cache_file = md.cache_file
    if cache_file is None or not same_file(cache_file.filepath, path):
        cache_file = next((cf for cf in bpy.data.cache_files if same_file(cf.filepath, path)), None)
    if cache_file is None:
        # There is no bpy.data.cache_files.new(); the operator is how a cache file is added.
        before = set(bpy.data.cache_files)
        bpy.ops.cachefile.open(filepath=path, relative_path=False)
        added = [cf for cf in bpy.data.cache_files if cf not in before]
        if not added:
            raise BakeError(f"Blender could not open the cache {path}")
        cache_file = added[0]
        cache_file.name = f"{MODIFIER_NAME} {obj.name}"
    # Assigning the path, even the same one, makes Blender reopen the stage.
    cache_file.filepath = stored_path(path)
    md.cache_file = cache_file
    md.object_path = "/" + prim_name
    md.read_data = read_data(md)
    set_float_colours(obj, _byte_colours_in(obj, path))


def detach_cache(obj) -> None:
    """Let the modifier pass the rest mesh through again; drop the cache file datablock when
    nothing else uses it, which also makes Blender close the files (needed before they are
    deleted or rewritten on Windows)."""
    md = find_modifier(obj)
    if md is None or md.cache_file is None:
        return
    cache_file = md.cache_file
    md.cache_file = None
    set_float_colours(obj, [])
    if cache_file.users == 0:
        bpy.data.batch_remove([cache_file])  # cache_files has no remove()


# ---------------------------------------------------------------------------------------------
# Byte colours in playback. Blender's USD reader writes colour primvars into float colour
# attributes only, and when the mesh it plays onto already has a BYTE colour of that name it
# leaves that layer as it is (white once the topology changes). So, while a cache that carries a
# byte colour is attached, a Geometry Nodes modifier right above "Tear Cloth" removes those byte
# layers from the reader's input and the reader makes them float colours of the same name. It is
# a stock node group saved in the .blend: playback needs no add-on. The bake never reads through
# it (blender/inputs.py switches it off with the modifiers below).

COLOUR_MODIFIER = "Tear Cloth Colours"


def _byte_colours_in(obj, path: str) -> list:
    """The object's byte colour attributes the cache at ``path`` carries."""
    from .. import cache
    try:
        carried = cache.cache_info(path)["primvars"]
    except cache.CacheError:
        return []
    return [a.name for a in obj.data.color_attributes if a.data_type == "BYTE_COLOR" and a.name in carried]


def set_float_colours(obj, names) -> None:
    """Make the byte colours ``names`` play as float colours (see above); none: remove the
    modifier and its node group."""
    md = obj.modifiers.get(COLOUR_MODIFIER)
    if not names:
        if md is not None:
            group = md.node_group
            obj.modifiers.remove(md)
            if group is not None and group.users == 0:
                bpy.data.node_groups.remove(group)
        return
    if md is None:
        md = obj.modifiers.new(COLOUR_MODIFIER, "NODES")
    group = md.node_group
    if group is None:
        group = bpy.data.node_groups.new(f"{COLOUR_MODIFIER} {obj.name}", "GeometryNodeTree")
        group.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
        group.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
        md.node_group = group
    group.nodes.clear()
    prev = group.nodes.new("NodeGroupInput").outputs[0]
    for name in names:
        node = group.nodes.new("GeometryNodeRemoveAttribute")
        node.inputs["Name"].default_value = name
        group.links.new(prev, node.inputs["Geometry"])
        prev = node.outputs["Geometry"]
    group.links.new(prev, group.nodes.new("NodeGroupOutput").inputs[0])
    mods = list(obj.modifiers)
    target = mods.index(find_modifier(obj))
    here = mods.index(md)
    if here != target - 1:
        obj.modifiers.move(here, target if here > target else target - 1)
