"""Tear Cloth settings stored in the .blend: ``Object.tearcloth`` and ``Scene.tearcloth``.

This file owns the property groups and their defaults. Lengths are FloatProperties with
``unit='LENGTH'`` (stored in Blender units, shown in the scene's units); ``convert.py`` turns them
into metres. Quantities Blender has no unit for (pascals, kg/m^3, N m, 1/s) are stored in SI.
Defaults are the "cotton" preset of ``materials.MATERIALS`` and the solver's own defaults.

``Object.tearcloth.haptics`` (``TearClothHapticSettings``) holds the live haptic session: one
``TearClothHapticHand`` per hand (device, grasped vertex group, workspace mapping, coupling), the
Falcon firmware path, recording and the stop button. Coupling values are SI (N/m, N s/m, N, a
force ratio); the region radius and the manual offset are lengths in scene units.
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


# -- haptics ---------------------------------------------------------------------------------------

HAPTIC_DEVICES = [
    ("FALCON", "Novint Falcon", "A Novint Falcon (by USB serial number; empty: any free one), with force feedback"),
    ("SPACEMOUSE", "SpaceMouse", "A 3Dconnexion SpaceMouse read through hidapi (input only, no force)"),
    ("KEYBOARD", "Keyboard / Mouse", "A virtual device moved with the arrow keys, Page Up/Down and Ctrl + mouse "
     "while the session runs (computes the force a Falcon would render)"),
    ("EMULATED", "Emulated Falcon (Demo)", "A Falcon emulator whose scripted hand pulls the grip away from the "
     "other hand: a demo without hardware"),
]

# (identifier, Falcon grip button bitmask): bit 0 plus, 1 forward, 2 centre, 3 minus. A SpaceMouse
# reports its left button as bit 0 and its right button as bit 1.
STOP_BUTTONS = {"NONE": 0, "CENTER": 0x4, "PLUS": 0x1, "FORWARD": 0x2, "MINUS": 0x8}


class TearClothHapticHand(PropertyGroup):
    """One hand of the live session: which device, what it grasps, how its motion and force map."""

    use: BoolProperty(name="Use", default=True, description="Grasp the cloth with this hand")
    device: EnumProperty(name="Device", items=HAPTIC_DEVICES, default="EMULATED",
                         description="What drives this hand")
    falcon_serial: StringProperty(
        name="Serial", description="USB serial number of the Falcon for this hand (Discover lists them); "
        "empty: any Falcon the other hand does not use")
    spacemouse_path: StringProperty(
        name="HID Path", description="hidapi path of the SpaceMouse for this hand (Discover lists them); empty: the "
        "first one found")
    vertex_group: StringProperty(name="Handle Group",
                                 description="Vertices this hand grasps (weight 0.5 or more)")
    mapping: EnumProperty(
        name="Workspace",
        items=[
            ("FIT", "Fit to Region", "The device's workspace ball maps onto a ball of the given radius around the "
             "grasped vertices; the grasp starts where the hand is"),
            ("MANUAL", "Scale and Offset", "Scene position = offset + scale x device position; the handle glides to "
             "the proxy when the session starts"),
        ],
        default="FIT", description="How device motion maps to the scene")
    region_radius: FloatProperty(
        name="Region Radius", default=0.08, min=1.0e-4, soft_max=2.0, unit="LENGTH", subtype="DISTANCE",
        description="Radius of the scene region the device's workspace covers")
    scale: FloatProperty(name="Scale", default=2.0, min=1.0e-3, soft_max=100.0,
                         description="Scene metres per metre of device motion")
    offset: FloatVectorProperty(name="Offset", size=3, default=(0.0, 0.0, 0.0), unit="LENGTH",
                                subtype="TRANSLATION",
                                description="Where the device's origin lies in the scene (world space)")
    k_position: FloatProperty(
        name="Stiffness", default=2000.0, min=0.0, soft_max=20000.0, precision=0,
        description="k_position of the proxy spring between the hand and the handle, in N/m (scene side)")
    k_velocity: FloatProperty(
        name="Damping", default=20.0, min=0.0, soft_max=200.0, precision=2,
        description="k_velocity: damping of the hand's velocity, in N s/m (scene side)")
    force_scale: FloatProperty(
        name="Force Scale", default=0.1, min=1.0e-4, soft_max=10.0, precision=3,
        description="Device force per newton of scene force (a tear of a few tens of N fits a Falcon's 8 N at 0.1)")
    max_force: FloatProperty(name="Max Force", default=8.0, min=0.0, soft_max=8.0, precision=2,
                             description="Largest force sent to the device, in N (a Falcon renders at most 8 N)")


class TearClothHapticSettings(PropertyGroup):
    """``Object.tearcloth.haptics``: the live haptic tearing session of this object."""

    left: PointerProperty(type=TearClothHapticHand, name="Left Hand")
    right: PointerProperty(type=TearClothHapticHand, name="Right Hand")
    firmware_path: StringProperty(
        name="Falcon Firmware", subtype="FILE_PATH",
        description="nvent_firmware.bin from your Novint driver or SDK: a Falcon needs it after every power-up and "
                    "Tear Cloth cannot ship it. Empty: the Falcons must have firmware loaded already")
    record: BoolProperty(
        name="Record to Cache", default=False,
        description="Write the session into this object's cache (as a bake does), from the Start frame on at the "
                    "scene's frame rate, so it can be played back and rendered through the Tear Cloth modifier")
    stop_button: EnumProperty(
        name="Stop Button",
        items=[
            ("NONE", "None", "Only Esc (or Stop) ends the session"),
            ("CENTER", "Centre", "The Falcon's centre grip button"),
            ("PLUS", "Plus / Button 1", "The Falcon's plus button, a SpaceMouse's left button"),
            ("FORWARD", "Forward / Button 2", "The Falcon's forward button, a SpaceMouse's right button"),
            ("MINUS", "Minus", "The Falcon's minus button"),
        ],
        default="CENTER", description="A grip button that ends the session (it must be seen released once first)")
    time_step: FloatProperty(
        name="Time Step", default=1.0e-3, min=1.0e-5, max=0.05, precision=5, step=0.01,
        description="Simulated seconds per step of the live session (the simulation runs as fast as it can)")
    keyboard_step: FloatProperty(
        name="Key Step", default=0.002, min=1.0e-5, soft_max=0.02, precision=4,
        description="Keyboard device: metres of device motion per arrow-key press (Shift: five times more)")
    demo_pull: FloatProperty(
        name="Demo Pull", default=0.02, min=0.0, max=0.04, precision=3,
        description="Emulated Falcon: how far (device metres) its scripted hand pulls the grip")
    demo_hold: FloatProperty(name="Demo Hold", default=0.3, min=0.0, soft_max=10.0, precision=2,
                             description="Emulated Falcon: seconds its hand holds still before pulling")
    demo_pull_time: FloatProperty(name="Demo Pull Time", default=2.0, min=0.01, soft_max=60.0, precision=2,
                                  description="Emulated Falcon: seconds the pull takes")
    demo_pace: EnumProperty(
        name="Demo Pace",
        items=[("SIMULATION", "Simulated Time", "The scripted hands follow the simulated time (the same pull on any "
                "machine)"),
               ("WALL", "Real Time", "The scripted hands move in real time, like a user")],
        default="SIMULATION", description="Which clock the emulated Falcons' scripted hands follow")
    force_log_folder: StringProperty(
        name="Force Log Folder", default="//", subtype="DIR_PATH",
        description="Where Save Force Log writes the CSV and the plot ('//' = next to the .blend file)")


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
        **_BLEND_RELATIVE,
    )
    frame_start: IntProperty(name="Start", default=1, min=-1048574, max=1048574,
                             description="First frame of the bake (the rest state)")
    frame_end: IntProperty(name="End", default=250, min=-1048574, max=1048574,
                           description="Last frame of the bake")

    # -- haptics -------------------------------------------------------------------------------
    haptics: PointerProperty(type=TearClothHapticSettings, name="Haptics")


class TearClothSceneSettings(PropertyGroup):
    """``Scene.tearcloth``: settings that concern every Tear Cloth object of the scene."""

    alembic_path: StringProperty(
        name="Alembic File", default="//tearcloth.abc", subtype="FILE_PATH",
        description="Where Export Alembic writes the baked Tear Cloth objects",
    )


classes = (TearClothHandle, TearClothCollider, TearClothHapticHand, TearClothHapticSettings,
           TearClothObjectSettings, TearClothSceneSettings)


def register_properties() -> None:
    bpy.types.Object.tearcloth = PointerProperty(type=TearClothObjectSettings, name="Tear Cloth")
    bpy.types.Scene.tearcloth = PointerProperty(type=TearClothSceneSettings, name="Tear Cloth")


def unregister_properties() -> None:
    for owner in (bpy.types.Object, bpy.types.Scene):
        if hasattr(owner, "tearcloth"):
            del owner.tearcloth
