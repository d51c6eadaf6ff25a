"""Scalar geometric primitives shared by every numba kernel of the library (issue 37: each
exists once): the tie rule of the edge functions.

An edge function ``E(p) = e x (p - q)`` (``e``: the edge vector, ``q``: a point of the edge) is
exactly zero for a point ``p`` on the edge. Which of the two triangles sharing the edge owns
that point (a fine-grid sample of the fast engine's raster, a pixel centre of the pose
gradients, a ray of the watertight intersection or of the Monte Carlo's crossings) is decided
by moving it off the edge by ``(eps, eps * delta)`` (``eps``, then ``delta``, to ``0+``):
``E`` becomes ``eps * (-ey + delta * ex)``, positive when ``ey < 0``, or ``ey == 0`` and
``ex > 0`` (``tie_positive``; a "top-left" rule). The neighbour sees the edge as ``-e``
and gets the other sign, so exactly one of the two triangles takes the point.

The helper is compiled by numba (``cache=True``) and inlined by LLVM into each kernel that
calls it; its Python function (``tie_positive.py_func``) also takes NumPy arrays, for the
vectorised :func:`xray_viz.tracing.intersect.watertight_intersect`. A change here reaches the
cached kernels of other modules through the callee digest of
``xray_viz.tracing._numba_cache``.
"""

from __future__ import annotations

from numba import njit

from xray_viz.tracing import _numba_cache  # noqa: F401  (where the helper below is cached)

__all__ = ["tie_positive"]


@njit(cache=True, nogil=True, error_model="numpy")
def tie_positive(ex, ey):
    """The tie rule: whether an edge function of edge vector ``(ex, ey)`` that is exactly zero
    counts as positive (the lexicographic sign of ``(-ey, ex)`` is +1). False for a zero edge
    (no triangle with area has one). Branch free: scalars in numba, or NumPy arrays."""
    return (ey < 0) | ((ey == 0) & (ex > 0))
