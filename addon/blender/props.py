"""Tear Cloth settings stored in the .blend: ``Object.tearcloth`` and ``Scene.tearcloth``.

This file owns the property groups and their defaults. Lengths are FloatProperties with
``unit='LENGTH'`` (stored in Blender units, shown in the scene's units); ``convert.py`` turns them
into metres. Quantities Blender has no unit for (pascals, kg/m^3, N m, 1/s) are stored in SI.
Defaults are the "cotton" preset of ``materials.MATERIALS`` and the solver's own defaults.
"""
from __future__ import annotations

import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)
from bpy.types import PropertyGroup

from ..materials import MATERIALS
from ..session import CollisionSettings
from .modifier import DEFAULT_CACHE_FOLDER

_COTTON = MATERIALS["cotton"]
_COLLISION = CollisionSettings()
# Object types that evaluate to a surface a cloth can hit.
COLLIDER_TYPES = {"MESH", "CURVE", "SURFACE", "FONT", "META"}


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
    object: PointerProperty(
        type=bpy.types.Object,
        name="Collider",
        description="Object the cloth collides with, read with its modifiers and armature every frame",
        poll=_collider_poll,
    )


class TearClothObjectSettings(PropertyGroup):
    """``Object.tearcloth``: how one mesh tears, and where its bake goes."""

    # -- material (SI except thickness, a length) ----------------------------------------------
    material_preset: StringProperty(
        name="Preset", default=_COTTON.name,
        description="Material preset last applied (editing a value keeps the name)",
    )
    young: FloatProperty(
        name="Young's Modulus", default=_COTTON.young, min=1.0, soft_max=1.0e10, precision=0, step=1e6,
        description="In-plane stiffness E of the sheet material, in pascals",
    )
    poisson: FloatProperty(
        name="Poisson Ratio", default=_COTTON.poisson, min=-0.99, max=0.49, precision=3,
        description="Lateral contraction under stretch, nu",
    )
    thickness: FloatProperty(
        name="Thickness", default=_COTTON.thickness, min=1.0e-6, max=1.0, precision=5, step=0.01,
        unit="LENGTH", subtype="DISTANCE",
        description="Sheet thickness h (stress = force per width / h)",
    )
    density: FloatProperty(
        name="Density", default=_COTTON.density, min=1.0e-3, max=1.0e5, precision=1,
        description="Volumetric density in kg/m^3 (areal mass = density x thickness)",
    )
    tear_stress: FloatProperty(
        name="Tear Stress", default=_COTTON.tear_stress, min=1.0, soft_max=1.0e9, precision=0, step=1e5,
        description="Largest principal stress at which the sheet tears (sigma_E of the paper), in pascals",
    )
    snap_tolerance: FloatProperty(
        name="Snap Tolerance", default=_COTTON.snap_tolerance, min=0.0, max=0.49, precision=2,
        description="A tear passing this close to a vertex (fraction of an edge) goes through it, "
                    "so tears make few and well-shaped new triangles",
    )
    bending: FloatProperty(
        name="Bending", default=_COTTON.bending, min=0.0, soft_max=1.0, precision=6, step=0.001,
        description="Bending stiffness in N m",
    )
    damping_mass: FloatProperty(
        name="Mass Damping", default=_COTTON.damping_mass, min=0.0, soft_max=100.0, precision=3,
        description="Rayleigh damping proportional to mass (alpha), in 1/s: air drag",
    )
    damping_stiffness: FloatProperty(
        name="Stiffness Damping", default=_COTTON.damping_stiffness, min=0.0, soft_max=0.01, precision=6,
        step=0.001, description="Rayleigh damping proportional to stiffness (beta), in seconds: internal friction",
    )

    # -- quality -------------------------------------------------------------------------------
    steps_per_frame: IntProperty(
        name="Steps per Frame", default=10, min=1, max=1000,
        description="Simulation steps per frame; the time step is 1 / (fps x steps)",
    )
    cg_tolerance: FloatProperty(
        name="CG Tolerance", default=1.0e-3, min=1.0e-12, max=0.5, precision=6,
        description="Relative residual at which the conjugate-gradient solve of each step stops",
    )
    cg_max_iterations: IntProperty(
        name="CG Iterations", default=200, min=1, max=100000,
        description="Most conjugate-gradient iterations per step",
    )
    use_tearing: BoolProperty(
        name="Tearing", default=True,
        description="Let the sheet tear where its stress exceeds the tear stress",
    )
    scan_period: IntProperty(
        name="Scan Period", default=16, min=1, max=10000,
        description="Steps for one sweep of the whole mesh for new tears while a tear runs",
    )
    min_angle_deg: FloatProperty(
        name="Min Angle", default=10.0, min=0.0, max=30.0, precision=1,
        description="No triangle made by a tear gets a smaller angle (degrees)",
    )

    # -- pins and handles ----------------------------------------------------------------------
    pin_group: StringProperty(
        name="Pin Group",
        description="Vertices held in place (weight 0.5 or more); empty: none",
    )
    handles: CollectionProperty(type=TearClothHandle, name="Handles")
    active_handle_index: IntProperty(name="Active Handle", default=0, min=0)

    # -- weak seams ----------------------------------------------------------------------------
    seam_group: StringProperty(
        name="Seam Group",
        description="Vertices that tear more easily: the tear stress there is scaled towards the factor "
                    "by the vertex weight",
    )
    seam_factor: FloatProperty(
        name="Strength", default=0.5, min=0.01, max=1.0, precision=2, subtype="FACTOR",
        description="Fraction of the tear stress where the seam weight is 1",
    )

    # -- collision -----------------------------------------------------------------------------
    use_collision: BoolProperty(name="Collision", default=True,
                                description="Collide with the colliders listed here and, if on, with itself")
    colliders: CollectionProperty(type=TearClothCollider, name="Colliders")
    active_collider_index: IntProperty(name="Active Collider", default=0, min=0)
    collider_collection: PointerProperty(
        type=bpy.types.Collection, name="Collection",
        description="Every object in this collection (and its children) is a collider too",
    )
    collision_thickness: FloatProperty(
        name="Distance", default=_COLLISION.thickness, min=1.0e-6, soft_max=0.1, precision=4,
        unit="LENGTH", subtype="DISTANCE",
        description="Contact distance kept between the cloth and surfaces",
    )
    friction: FloatProperty(
        name="Friction", default=_COLLISION.friction, min=0.0, soft_max=2.0, max=99.0, precision=2,
        description="Coulomb friction coefficient",
    )
    use_self_collision: BoolProperty(name="Self Collision", default=_COLLISION.self_collision,
                                     description="Keep the cloth from passing through itself")
    cluster_size: IntProperty(
        name="Cluster Size", default=_COLLISION.cluster_size, min=4, max=100000,
        description="Vertices per cluster: collision detection skips cluster pairs that moved little",
    )
    displacement_threshold: FloatProperty(
        name="Displacement Threshold", default=_COLLISION.displacement_threshold, min=1.0e-7, soft_max=0.1,
        precision=4, unit="LENGTH", subtype="DISTANCE",
        description="Relative motion of two clusters that triggers a full detection between them",
    )
    measure: EnumProperty(
        name="Measure",
        items=[
            ("RELATIVE", "Relative", "Displacement of each cluster pair relative to each other (the paper)"),
            ("ABSOLUTE", "Absolute", "Displacement of each cluster on its own"),
            ("FULL", "Full", "Detect every close pair every step (slow; a reference)"),
        ],
        default=_COLLISION.measure.upper(),
        description="When a cluster pair is checked again",
    )

    # -- cache ---------------------------------------------------------------------------------
    cache_folder: StringProperty(
        name="Folder", default=DEFAULT_CACHE_FOLDER, subtype="DIR_PATH",
        description="Where the bake goes ('//' = next to the .blend file); one USD file per object",
    )
    frame_start: IntProperty(name="Start", default=1, min=-1048574, max=1048574,
                             description="First frame of the bake (the rest state)")
    frame_end: IntProperty(name="End", default=250, min=-1048574, max=1048574,
                           description="Last frame of the bake")


class TearClothSceneSettings(PropertyGroup):
    """``Scene.tearcloth``: settings that concern every Tear Cloth object of the scene."""

    alembic_path: StringProperty(
        name="Alembic File", default="//tearcloth.abc", subtype="FILE_PATH",
        description="Where Export Alembic writes the baked Tear Cloth objects",
    )


classes = (TearClothHandle, TearClothCollider, TearClothObjectSettings, TearClothSceneSettings)


def register_properties() -> None:
    bpy.types.Object.tearcloth = PointerProperty(type=TearClothObjectSettings, name="Tear Cloth")
    bpy.types.Scene.tearcloth = PointerProperty(type=TearClothSceneSettings, name="Tear Cloth")


def unregister_properties() -> None:
    for owner in (bpy.types.Object, bpy.types.Scene):
        if hasattr(owner, "tearcloth"):
            del owner.tearcloth
