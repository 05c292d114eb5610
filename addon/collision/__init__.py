"""Clustered ray-traced collision detection of cloth (issue 4; paper section IV).

Pure Python + numpy + embreex. What each file owns:

* ``clusters``    geodesic k-means decomposition of a mesh, its local update after a tear
* ``measure``     per-cluster displacement, cluster AABBs, close pairs, relative / absolute measure
* ``narrow``      Embree scenes per cluster (rigid-frame cache), contact classification, ``Contacts``
* ``incremental`` exact line/triangle tests and the walk over triangle adjacency
* ``detector``    ``CollisionDetector``: the per-step orchestration and the brute-force reference
* ``bench``       ``collision_experiment``: full / absolute / relative timings of a scene
* ``preview``     PNG of a cluster decomposition (matplotlib, Agg)
"""
from .clusters import Clustering, cluster_mesh
from .detector import CollisionDetector
from .narrow import Contacts

__all__ = ["CollisionDetector", "Contacts", "Clustering", "cluster_mesh"]
