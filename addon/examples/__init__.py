"""Procedural example geometry of Tear Cloth: the paper's square cloth, banknote and T-shirt, and
the walking mannequin the shirt is worn by. Dev-only: the benchmarks, the tests,
``example_blends/make_examples.py`` and ``tearcloth demo`` start from these meshes; the Blender
extension zip leaves this package out (it needs scipy, which Blender does not ship).

One file per thing:
  * ``mesh``       ``ClothMesh``, ``validate_mesh``, ``refine`` and the shared topology helpers
  * ``mesher``     the irregular 2-D mesher (``delaunay_2d``, ``triangulate_polygon``)
  * ``mannequin``  ``Body``, ``mannequin``: the closed body, its bones and skinning weights
  * ``walk``       ``bone_matrices``, ``body_pose``, ``WALK_END``: the walk, then the reach
  * ``distance``   ``closest_points`` and the per-part distances of the shirt fit
  * ``shirt``      the T-shirt's pattern, sewing, wrap, fit and clean-up
  * ``scenes``     ``square_cloth``, ``banknote``, ``tshirt``, ``denim_knee`` (and the leg's
                   ``capsule``): the scenes, assembled

Everything is in SI units (metres, seconds), Z up, characters and sheets facing -Y.
"""
try:
    import scipy.sparse.csgraph  # noqa: F401  (the one dependency beyond numpy)
except ImportError as exc:  # pragma: no cover - depends on the environment
    raise ImportError(
        "tearcloth.examples (example geometry for the bench, the demo and the tests) needs scipy: "
        "pip install 'tearcloth[bench]'"
    ) from exc

from .distance import closest_points
from .mannequin import Body, mannequin
from .mesh import MIN_TARGET_TRIANGLES, ClothMesh, refine, validate_mesh
from .mesher import delaunay_2d, triangulate_polygon
from .scenes import BANKNOTE_SIZE, LEG, banknote, capsule, denim_knee, square_cloth, tshirt
from .walk import WALK_END, body_pose, bone_matrices

__all__ = [
    "ClothMesh",
    "Body",
    "MIN_TARGET_TRIANGLES",
    "delaunay_2d",
    "triangulate_polygon",
    "validate_mesh",
    "refine",
    "closest_points",
    "square_cloth",
    "BANKNOTE_SIZE",
    "banknote",
    "mannequin",
    "body_pose",
    "bone_matrices",
    "WALK_END",
    "tshirt",
    "LEG",
    "capsule",
    "denim_knee",
]
