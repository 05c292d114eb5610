"""Tear Cloth settings stored in the .blend: ``Object.tearcloth`` and ``Scene.tearcloth``.

This file owns the property groups. Every setting is built from its row of ``settings.py``
(``blender_property``): the label, the description, the default, min/max from the hard bounds,
soft_min/soft_max from the soft bounds, and lengths in the scene as FloatProperties with
``unit='LENGTH'`` (stored in Blender units, shown in the scene's units; ``convert.py`` turns them
into metres). Quantities Blender has no unit for (pascals, kg/m^3, N m, 1/s) are stored in SI;
lengths in a device's frame (the keyboard step, the demo pull) are plain numbers of metres.
Written out here are only what is not a setting: the handle and collider lists, their active
indices and the pointers that hang the groups together.

Property names are the RNA names existing .blend files store; the table's ``rna`` column keeps
them where the table's own name differs (see settings.py).

``Object.tearcloth.haptics`` (``TearClothHapticSettings``) holds the live haptic session: one
``TearClothHapticHand`` per hand (device, grasped vertex group, workspace mapping, coupling), the
Falcon firmware path, recording and the stop button.
"""
from __future__ import annotations

import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)
from bpy.types import PropertyGroup

# Blender 5.0 warns when a script sets a '//' path on a property that does not declare it may be
# relative to the .blend; older ones do not know the option.
_BLEND_RELATIVE = {"options": {"PATH_SUPPORTS_BLEND_RELATIVE"}} if bpy.app.version >= (5, 0, 0) else {}

from .. import settings as table

# Object types that evaluate to a surface a cloth can hit.
COLLIDER_TYPES = {"MESH", "CURVE", "SURFACE", "FONT", "META"}

# (identifier, Falcon grip button bitmask): bit 0 plus, 1 forward, 2 centre, 3 minus. A SpaceMouse
# reports its left button as bit 0 and its right button as bit 1. Keys: the stop_button row's values.
STOP_BUTTONS = {"NONE": 0, "CENTER": 0x4, "PLUS": 0x1, "FORWARD": 0x2, "MINUS": 0x8}


def _bounds(row, bounds, lo_key, hi_key, cast):
    """min/max (or soft_min/soft_max) keywords of a row's bounds; an open side is given as its
    end point (Blender has no open intervals; the validation refuses the end point itself)."""
    out = {}
    if bounds is not None and bounds.lo is not None:
        out[lo_key] = cast(bounds.lo)
    if bounds is not None and bounds.hi is not None:
        out[hi_key] = cast(bounds.hi)
    return out


def blender_property(row):
    """The bpy property of one settings row: name, description, default, min/max = hard bounds,
    soft_min/soft_max = soft bounds, scene lengths with unit LENGTH (shown in scene units)."""
    common = dict(name=row.label, description=row.description)
    hints = dict(row.ui)
    hints.pop("when", None)  # a layout rule for ui.py, not a property option
    options = _BLEND_RELATIVE if hints.pop("blend_relative", False) else {}
    if row.kind in ("float", "vector"):
        if row.is_scene_length:
            # Stored in Blender units, bounded in metres: a bound in BU is another length in every
            # unit scale (the 1 m cap on thickness was 1 cm in a centimetre scene, and a 2 cm sheet
            # was clamped to 1 cm without a word). Only a zero bound means the same in all; the
            # rest are checked in metres when the values are used (Material / CollisionSettings
            # validate, naming the value, its unit and the bound).
            kw = dict(common, **hints, unit="LENGTH", subtype="TRANSLATION" if row.kind == "vector" else "DISTANCE")
            if row.hard is not None and row.hard.lo == 0:
                kw["min"] = 0.0
        else:
            kw = dict(common, **_bounds(row, row.hard, "min", "max", float),
                      **_bounds(row, row.soft, "soft_min", "soft_max", float), **hints)
            if row.unit == "rad":  # stored in radians (SI), shown in the scene's rotation units
                kw.update(unit="ROTATION", subtype="ANGLE")
        if row.kind == "vector":
            return FloatVectorProperty(size=len(row.default), default=row.default, **kw)
        return FloatProperty(default=row.default, **kw)
    if row.kind == "int":
        return IntProperty(default=row.default, **common, **_bounds(row, row.hard, "min", "max", int),
                           **_bounds(row, row.soft, "soft_min", "soft_max", int), **hints)
    if row.kind == "bool":
        return BoolProperty(default=row.default, **common)
    if row.kind == "enum":
        items = [(value.upper(), label, text) for value, label, text in row.items]
        return EnumProperty(items=items, default=row.default.upper(), **common)
    subtype = {"file": "FILE_PATH", "dir": "DIR_PATH"}.get(row.kind, "NONE")
    return StringProperty(default=row.default, subtype=subtype, **common, **options)


def table_properties(*groups) -> dict:
    """Annotations for a property group: every row of the groups that Blender stores, by RNA name."""
    return {row.blender_name: blender_property(row) for group in groups for row in table.rows(group)
            if row.blender_name is not None}


def _not_owner(self, obj):
    return obj is not self.id_data


def _collider_poll(self, obj):
    return obj.type in COLLIDER_TYPES and obj is not self.id_data


class TearClothHandle(PropertyGroup):
    """A handle (the paper's word): vertices grasped together and moved as one."""

    vertex_group: StringProperty(
        name="Vertex Group",
        description="Vertices this handle grasps (weight 0.5 or more)",
    )
    follow: PointerProperty(
        type=bpy.types.Object,
        name="Follow",
        description=(
            "Object (e.g. an empty) whose animated matrix drives the handle: the grasped vertices "
            "move as the object moves from the bake's first frame on. Empty: the handle holds still"
        ),
        poll=_not_owner,
    )


class TearClothCollider(PropertyGroup):
    """One entry of the collider list."""

    object: PointerProperty(
        type=bpy.types.Object,
        name="Collider",
        description="Object the cloth collides with, read with its modifiers and armature every frame",
        poll=_collider_poll,
    )


class TearClothHapticHand(PropertyGroup):
    """One hand of the live session: which device, what it grasps, how its motion and force map
    (the "hand" rows of the settings table)."""

    __annotations__ = table_properties("hand")


class TearClothHapticSettings(PropertyGroup):
    """``Object.tearcloth.haptics``: the live haptic tearing session of this object (the
    "haptics" rows of the settings table and one hand each side)."""

    __annotations__ = {
        "left": PointerProperty(type=TearClothHapticHand, name="Left Hand",
                                description="The left hand of the live session: its device, what it grasps, its coupling"),
        "right": PointerProperty(type=TearClothHapticHand, name="Right Hand",
                                 description="The right hand of the live session: its device, what it grasps, its coupling"),
        **table_properties("haptics"),
    }


class TearClothObjectSettings(PropertyGroup):
    """``Object.tearcloth``: how one mesh tears, and where its bake goes (the material, solver,
    tearing, pins, collision and cache rows of the settings table, plus the lists)."""

    __annotations__ = {
        **table_properties("material", "solver", "tearing", "pins", "collision", "cache"),
        "handles": CollectionProperty(
            type=TearClothHandle, name="Handles",
            description="Handles: vertex groups grasped together, each moved as one by its follow object"),
        "active_handle_index": IntProperty(
            name="Active Handle", default=0, min=0, description="Index of the handle selected in the list"),
        "colliders": CollectionProperty(
            type=TearClothCollider, name="Colliders",
            description="Objects the cloth collides with (besides those in the collider collection)"),
        "active_collider_index": IntProperty(
            name="Active Collider", default=0, min=0, description="Index of the collider selected in the list"),
        "collider_collection": PointerProperty(
            type=bpy.types.Collection, name="Collection",
            description="Every object in this collection (and its children) is a collider too"),
        "haptics": PointerProperty(
            type=TearClothHapticSettings, name="Haptics",
            description="The live haptic session of this object: devices, what each hand grasps, coupling"),
    }


class TearClothSceneSettings(PropertyGroup):
    """``Scene.tearcloth``: settings that concern every Tear Cloth object of the scene."""

    __annotations__ = table_properties("export")


classes = (TearClothHandle, TearClothCollider, TearClothHapticHand, TearClothHapticSettings,
           TearClothObjectSettings, TearClothSceneSettings)


def register_properties() -> None:
    bpy.types.Object.tearcloth = PointerProperty(type=TearClothObjectSettings, name="Tear Cloth",
                                                 description="Tear Cloth settings of this object")
    bpy.types.Scene.tearcloth = PointerProperty(type=TearClothSceneSettings, name="Tear Cloth",
                                                description="Tear Cloth settings of this scene")


def unregister_properties() -> None:
    for owner in (bpy.types.Object, bpy.types.Scene):
        if hasattr(owner, "tearcloth"):
            del owner.tearcloth
