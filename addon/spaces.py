"""World metres <-> an object's local space in scene units, as plain numpy (no bpy).

What this file owns: the few matrix formulas that carry positions, velocities and handle targets
between the simulation's space (world, metres) and a Blender object's (local, Blender units).
They live here, below the Blender layer, because the bpy-free bake job (``bake.py``) writes its
cache in the object's local space, and the Blender layer (``blender/convert.py``, the live
recorder) needs the same formulas: one copy for both.

``matrix_world`` is the object's 4x4 world matrix in Blender units; ``scale`` is metres per
Blender unit (the scene's ``unit_settings.scale_length``).
"""
from __future__ import annotations

import numpy as np


def transform_points(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ matrix[:3, :3].T + matrix[:3, 3]


def local_to_world_si(points_local: np.ndarray, matrix_world: np.ndarray, scale: float) -> np.ndarray:
    """Object-local BU -> world metres."""
    return transform_points(matrix_world, points_local) * scale


def world_si_to_local(points_si: np.ndarray, matrix_world: np.ndarray, scale: float) -> np.ndarray:
    """World metres -> object-local BU."""
    return transform_points(np.linalg.inv(matrix_world), points_si / scale)


def world_si_vectors_to_local(vectors_si: np.ndarray, matrix_world: np.ndarray, scale: float) -> np.ndarray:
    """Velocities: world m/s -> object-local BU/s (only the linear part of the inverse acts)."""
    return (vectors_si / scale) @ np.linalg.inv(matrix_world[:3, :3]).T


def handle_target_si(current: np.ndarray, grasp: np.ndarray, scale: float) -> np.ndarray:
    """A handle's affine target, in metres, for a follow object whose world matrix was ``grasp``
    when the cloth was grasped and is ``current`` now: target = current @ grasp^-1, the motion of
    the follow object since the grasp, applied to the grasped vertices. Rotation and scale act on
    metres and BU alike; only the translation column changes unit."""
    target = current @ np.linalg.inv(grasp)
    target[:3, 3] *= scale
    return target
