"""Benchmarks of Tear Cloth (``tearcloth bench``, ``tearcloth clusters``): dev-only, left out of the
Blender extension zip. They measure the shipped package on this machine; nothing in the package
imports them.

One file per part:
  * ``suite``      ``run``: every part in one run, console tables, JSON, BENCHMARKS.md
  * ``table1``     the paper's Table I: FEM and tearing per step on its three scenarios
  * ``collision``  the paper's collision experiment (worn T-shirt, three measures), the stand-in
                   scene, and ``cluster_picture`` (Fig. 2)
  * ``servo``      servo timing over emulated Falcons (``measure_servo``, ``measure_live_servo``)
  * ``race``       the race against Blender's cloth (its bpy half is ``tearcloth.blender.race``)
  * ``scaling``    step time and memory from 1K to 100K triangles, one child process per point
  * ``cache``      writing speed of the USD bake cache
  * ``report``     BENCHMARKS.md from one run's results
  * ``machine``    the load average recorded with the results
  * ``preview``    ``render_clusters``: a PNG of clusters (matplotlib), for ``cluster_picture``

The scenes come from ``tearcloth.examples``, which needs scipy (``pip install 'tearcloth[bench]'``);
without it, importing this package fails with that instruction.
"""
from .collision import cluster_picture
from .suite import PARTS, run

__all__ = ["run", "PARTS", "cluster_picture"]
