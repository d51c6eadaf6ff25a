"""The reference engine: every hit of every detector ray in NumPy, swept in order of ``t``.

Watertight Moller-Trumbore on culled ray-triangle pairs (:func:`xray_viz.tracing.hits.trace_rays`)
gives every hit; :func:`xray_viz.attenuation.path_lengths` sweeps them into effective path
lengths. Registered as ``"numpy"`` in :data:`xray_viz.tracing.engines.ENGINES`; the fast engine
falls back to it where it cannot trace (hits asked for, a one-pixel-wide supersampled detector).
"""

from __future__ import annotations

from xray_viz.attenuation import path_lengths as _sweep_path_lengths
from xray_viz.tracing.hits import trace_rays

__all__ = ["numpy_path_lengths", "numpy_rows"]


def numpy_path_lengths(scene, *, supersample=1, keep_hits=False, rows=None):
    """The NumPy engine on a scene (anything with ``bodies`` and ``acquisition``).

    A public adapter: the scene's bodies and acquisition go to the function the engines use.

    Parameters
    ----------
    scene : Scene
    supersample : int, optional
    keep_hits : bool, optional
        Also return every hit (:class:`~xray_viz.tracing.hits.Hits`).
    rows : (int, int), optional
        Only the rays of these image rows (:func:`~xray_viz.geometry.detector_rays`).

    Returns
    -------
    L : (rays, n_bodies) float
        Path lengths (mm).
    hits : Hits or None
    """
    return _path_lengths(scene.bodies, scene.acquisition, supersample=supersample,
                         keep_hits=keep_hits, rows=rows)


def _path_lengths(bodies, acq, *, supersample=1, keep_hits=False, rows=None):
    """:func:`numpy_path_lengths` of ``bodies`` seen by the acquisition ``acq``."""
    rays = acq.rays(supersample=supersample, rows=rows)
    hits = trace_rays(bodies, rays.origins, rays.directions, t_min=0.0, t_max=rays.t_max,
                      axis=acq.frame.forward)
    L = _sweep_path_lengths(hits.ray, hits.t, hits.body, hits.entering, n_rays=len(rays),
                            n_bodies=len(bodies), precedence=bodies.precedence,
                            t_max=rays.t_max)
    return L, (hits if keep_hits else None)


def numpy_rows(scene, *, supersample=1, rows=None):
    """The NumPy engine by windows of ``rows`` image rows: yields ``(r0, r1, L)`` as
    :func:`xray_viz.tracing.fast.trace_rows` does (a public adapter, as
    :func:`numpy_path_lengths`)."""
    return _rows(scene.bodies, scene.acquisition, supersample=supersample, rows=rows)


def _rows(bodies, acq, *, supersample=1, rows=None):
    """:func:`numpy_rows` of ``bodies`` seen by the acquisition ``acq``."""
    h = acq.detector.shape[1]
    step = h if rows is None else max(1, int(rows))
    for r0 in range(0, h, step):
        r1 = min(h, r0 + step)
        yield r0, r1, _path_lengths(bodies, acq, supersample=supersample, rows=(r0, r1))[0]
