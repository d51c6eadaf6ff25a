"""Tracing: every intersection of every ray with the scene's triangles.

* :func:`trace_rays` - any rays, every hit (the reference NumPy engine).
* :mod:`~xray_viz.tracing.intersect` - the ray-triangle tests (thesis Moller-Trumbore and
  its watertight form).
* :mod:`~xray_viz.tracing.candidates` - culling of ray-triangle pairs.
"""

from xray_viz.tracing.hits import Hits, trace_rays, trace_triangles
from xray_viz.tracing.intersect import moller_trumbore, watertight_intersect

__all__ = ["Hits", "trace_rays", "trace_triangles", "moller_trumbore", "watertight_intersect"]
