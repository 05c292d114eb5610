"""Clustered ray-traced collision detection of cloth (issue 4; paper section IV).

Python orchestrates; every loop over vertices, rays, triangles or cluster pairs runs in C
(``tearcloth._collide``, sources ``native/collide/``); Embree (embreex) casts the rays of full
detection into the bodies, native refitted BVHs (``native/collide/bvh.c``) those into the cloth
itself. What each file owns:

* ``clusters``    geodesic k-means decomposition of a mesh, its local update after a tear
* ``measure``     per-cluster displacement, cluster AABBs, close pairs, relative / absolute measure
* ``narrow``      Embree scenes per body cluster (rigid-frame cache), the cloth's refitted BVHs,
                  contact classification, ``Contacts``
* ``incremental`` exact line/triangle tests and the walk over triangle adjacency
* ``detector``    ``CollisionDetector``: the per-step orchestration
* ``kernels``     the calls into the C kernels (outputs, growing workspaces)

Dev-only companions live elsewhere: the timing experiment in ``tearcloth.bench.collision``, the
numpy specifications of the contact kernels and the brute-force detection in
``tests/collision_reference.py``.

The numpy functions of ``measure``, ``incremental`` and ``narrow`` are the specification of the
kernel that does their job in the detector; they stay public and tested.
"""
from .clusters import Clustering, cluster_mesh
from .detector import CollisionDetector
from .narrow import Contacts

__all__ = ["CollisionDetector", "Contacts", "Clustering", "cluster_mesh"]
