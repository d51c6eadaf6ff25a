"""The main job: render a scene's radiograph.

scene -> rays (:mod:`~xray_viz.geometry`) -> hits (:mod:`~xray_viz.tracing`) -> path lengths
(:mod:`~xray_viz.attenuation`) -> image (:mod:`~xray_viz.physics`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from xray_viz.attenuation import path_lengths
from xray_viz.geometry import detector_rays, viewport
from xray_viz.tracing.hits import Hits, trace_rays

__all__ = ["Radiograph", "render", "ENGINES", "QUANTITIES"]

#: Names accepted by ``--quantity`` and :meth:`Radiograph.quantity`.
QUANTITIES = ("intensity", "line-integral", "path-length")


@dataclass(frozen=True, eq=False)
class Radiograph:
    """A rendered radiograph.

    Arrays are in image orientation: shape ``(H, W)``, row 0 at the top of the detector
    (v = 1), column 0 at its left (u = 0), as seen from the source.

    Attributes
    ----------
    intensity : (H, W) float
        Detected intensity, ``I0 exp(-line_integral)`` for a monochromatic beam.
    line_integral : (H, W) float
        ``sum_b mu_b L_b`` (dimensionless), ``-ln(I / I0)``.
    path_length : (H, W, n_bodies) float
        Millimetres of each pixel's ray in each body's material (innermost / later body wins).
    body_names : list of str
    timing : dict
        Seconds spent in ``trace`` (rays, hits, path lengths), ``image`` and ``total``.
    engine : str
    hits : Hits or None
        Every hit of every ray, when asked for with ``keep_hits=True`` (numpy engine).
    """

    intensity: np.ndarray
    line_integral: np.ndarray
    path_length: np.ndarray
    body_names: list
    timing: dict
    engine: str
    scene: object = field(repr=False, default=None)
    hits: Hits | None = field(repr=False, default=None)

    @property
    def total_path_length(self) -> np.ndarray:
        """(H, W) float: millimetres of each ray inside any body."""
        return self.path_length.sum(axis=2)

    def quantity(self, name: str) -> np.ndarray:
        """The (H, W) image of ``"intensity"``, ``"line-integral"`` or ``"path-length"``."""
        if name == "intensity":
            return self.intensity
        if name in ("line-integral", "line_integral"):
            return self.line_integral
        if name in ("path-length", "path_length"):
            return self.total_path_length
        raise ValueError(f"unknown quantity {name!r}; choose one of {', '.join(QUANTITIES)}")


def _numpy_path_lengths(scene, *, supersample=1, keep_hits=False):
    rays = detector_rays(scene, supersample=supersample)
    vp = viewport(scene.source.position, scene.detector)
    hits = trace_rays(scene, rays.origins, rays.directions, t_min=0.0, t_max=rays.t_max,
                      axis=vp.forward)
    L = path_lengths(hits.ray, hits.t, hits.body, hits.entering, n_rays=len(rays),
                     n_bodies=len(scene.bodies), precedence=scene.precedence, t_max=rays.t_max)
    return L, (hits if keep_hits else None)


def _fast_path_lengths(scene, *, supersample=1, keep_hits=False):
    from xray_viz.tracing.fast import fast_path_lengths

    return fast_path_lengths(scene, supersample=supersample, keep_hits=keep_hits)


#: Rendering engines by name. ``fn(scene, *, supersample, keep_hits) -> (L, hits or None)`` where
#: ``L`` is ``(W * H * supersample**2, n_bodies)``: effective path lengths (mm) of the rays of
#: :func:`~xray_viz.geometry.detector_rays` ``(scene, supersample=supersample)``, in that order.
ENGINES = {"fast": _fast_path_lengths, "numpy": _numpy_path_lengths}


def render(scene, *, engine: str = "fast", supersample: int | None = None,
           keep_hits: bool = False) -> Radiograph:
    """Render the radiograph of a scene.

    Parameters
    ----------
    scene : Scene
        From :func:`xray_viz.load_scene`.
    engine : str
        ``"fast"`` (default): the watertight fixed-point footprint rasteriser of
        :mod:`xray_viz.tracing.fast` (numba). ``"numpy"``: the pure-NumPy reference engine
        (watertight Moller-Trumbore on culled ray-triangle pairs).
    supersample : int, optional
        ``n`` traces ``n x n`` rays per pixel and averages their intensities (anti-aliasing).
        Defaults to the scene's ``[detector] supersample`` (1 unless set).
    keep_hits : bool
        Keep every hit of every ray in :attr:`Radiograph.hits` (numpy engine).

    Returns
    -------
    Radiograph

    Examples
    --------
    >>> import xray_viz
    >>> image = xray_viz.render(xray_viz.load_scene("sphere"))
    >>> image.intensity.shape
    (256, 256)
    >>> round(float(image.total_path_length.max()), 1)      # the diameter, 80 mm
    80.0
    """
    if engine not in ENGINES:
        raise ValueError(f"unknown engine {engine!r}; choose one of {', '.join(ENGINES)}")
    from xray_viz.physics.imaging import detect_log, pixel_log_transmission

    n = int(scene.detector.supersample if supersample is None else supersample)
    if n < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    w, h = scene.detector.shape
    t0 = time.perf_counter()
    L, hits = ENGINES[engine](scene, supersample=n, keep_hits=keep_hits)
    t1 = time.perf_counter()
    # ln(I / I0) of every ray, averaged (in I) over each pixel's n x n rays, in the log domain;
    # with the variance's sum when the noise needs it (a band of rows: rows=(start, stop)).
    log_t, log_v = pixel_log_transmission(L, scene, supersample=n)
    intensity, line_integral = detect_log(log_t, scene, log_variance=log_v)
    t2 = time.perf_counter()
    timing = {"trace": t1 - t0, "image": t2 - t1, "total": t2 - t0}
    return Radiograph(
        intensity=intensity,
        line_integral=line_integral,
        path_length=L.reshape(h * w, n * n, -1).mean(axis=1).reshape(h, w, len(scene.bodies)),
        body_names=scene.body_names,
        timing=timing,
        engine=engine,
        scene=scene,
        hits=hits,
    )
