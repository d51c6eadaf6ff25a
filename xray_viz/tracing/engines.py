"""The rendering engines: one protocol, one registry.

An engine turns *what is imaged* (:class:`~xray_viz.bodies.Bodies`) and *how*
(:class:`~xray_viz.geometry.Acquisition`) into effective path lengths: ``L[ray, body]``, the
millimetres of each detector ray (in the order of :func:`xray_viz.geometry.detector_rays`)
inside each body's material. :func:`xray_viz.render` then applies the physics.

Two engines are registered in :data:`ENGINES`:

* ``"numpy"`` (:class:`NumpyEngine`): the reference. Every hit of every ray by watertight
  Moller-Trumbore on culled ray-triangle pairs (:func:`xray_viz.tracing.hits.trace_rays`), swept
  by :func:`xray_viz.attenuation.path_lengths`. It can return the hits.
* ``"fast"`` (:class:`FastEngine`): the watertight fixed-point footprint rasteriser of
  :mod:`xray_viz.tracing.fast` (numba); no hit list.

Both keep what they derive from the meshes on the bodies (:meth:`xray_viz.bodies.Bodies.cached`),
so a new acquisition of the same bodies pays no per-mesh set-up again.

Examples
--------
>>> import xray_viz
>>> from xray_viz.tracing.engines import ENGINES
>>> scene = xray_viz.load_scene("sphere")
>>> L = ENGINES["numpy"].path_lengths(scene.bodies, scene.acquisition)
>>> L.shape, round(float(L.max()), 1)
((65536, 1), 80.0)
>>> bool(abs(ENGINES["fast"].path_lengths(scene.bodies, scene.acquisition) - L).max() < 1e-9)
True
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

import numpy as np

from xray_viz.geometry import check_supersample
from xray_viz.tracing.reference import numpy_path_lengths, numpy_rows

__all__ = ["Engine", "NumpyEngine", "FastEngine", "ENGINES"]


class _Imaged(NamedTuple):
    """Bodies and an acquisition, where a scene-like pair is wanted."""

    bodies: object
    acquisition: object

    @property
    def source(self):
        return self.acquisition.source

    @property
    def detector(self):
        return self.acquisition.detector


class Engine(Protocol):
    """What a rendering engine provides.

    Attributes
    ----------
    name : str
        Its key in :data:`ENGINES` (``--engine`` on the command line).
    returns_hits : bool
        Whether :meth:`hits` can return every hit of every ray.
    """

    name: str
    returns_hits: bool

    def path_lengths(self, bodies, acquisition, *, supersample: int = 1) -> np.ndarray:
        """``(W * H * supersample**2, n_bodies)`` float: every detector ray's path lengths."""

    def windows(self, bodies, acquisition, *, supersample: int = 1, rows: int | None = None):
        """Yield ``(r0, r1, L)``: the path lengths of image rows ``r0 .. r1 - 1`` (windows of
        about ``rows`` rows, from the top), bit for bit those of :meth:`path_lengths`."""

    def __call__(self, scene, *, supersample: int = 1, keep_hits: bool = False):
        """``(L, hits or None)`` of a scene (``keep_hits``: every hit, where supported)."""


class NumpyEngine:
    """The pure-NumPy reference engine (watertight Moller-Trumbore on culled ray-triangle
    pairs, every hit swept in order of ``t``)."""

    name = "numpy"
    returns_hits = True

    def path_lengths(self, bodies, acquisition, *, supersample: int = 1) -> np.ndarray:
        """Path lengths of every detector ray (see :class:`Engine`)."""
        n = check_supersample(supersample)
        return numpy_path_lengths(_Imaged(bodies, acquisition), supersample=n)[0]

    def hits(self, bodies, acquisition, *, supersample: int = 1, rows=None):
        """``(L, hits)``: path lengths and every hit (:class:`~xray_viz.tracing.hits.Hits`,
        ray numbers within ``rows``)."""
        n = check_supersample(supersample)
        return numpy_path_lengths(_Imaged(bodies, acquisition), supersample=n,
                                   keep_hits=True, rows=rows)

    def windows(self, bodies, acquisition, *, supersample: int = 1, rows: int | None = None):
        """Path lengths window by window of image rows (see :class:`Engine`)."""
        n = check_supersample(supersample)
        yield from numpy_rows(_Imaged(bodies, acquisition), supersample=n, rows=rows)

    def __call__(self, scene, *, supersample: int = 1, keep_hits: bool = False):
        """``(L, hits or None)`` of a scene (see :class:`Engine`)."""
        n = check_supersample(supersample)
        return numpy_path_lengths(scene, supersample=n, keep_hits=keep_hits)

    def __repr__(self) -> str:
        return "NumpyEngine()"


class FastEngine:
    """The fast engine (:mod:`xray_viz.tracing.fast`): a watertight fixed-point footprint
    rasteriser in numba. Recent results of small detectors are kept on the bodies per
    acquisition, so re-rendering the same geometry with other energies or materials costs
    nothing."""

    name = "fast"
    returns_hits = False

    def path_lengths(self, bodies, acquisition, *, supersample: int = 1) -> np.ndarray:
        """Path lengths of every detector ray (see :class:`Engine`); read-only when kept."""
        from xray_viz.tracing.fast import fast_path_lengths

        return fast_path_lengths(_Imaged(bodies, acquisition), supersample=supersample)[0]

    def windows(self, bodies, acquisition, *, supersample: int = 1, rows: int | None = None):
        """Path lengths window by window of image rows (see :class:`Engine`)."""
        from xray_viz.tracing.fast import trace_rows

        yield from trace_rows(_Imaged(bodies, acquisition), supersample=supersample, rows=rows)

    def __call__(self, scene, *, supersample: int = 1, keep_hits: bool = False):
        """``(L, hits or None)`` of a scene; ``keep_hits`` asks the NumPy engine for the hits."""
        from xray_viz.tracing.fast import fast_path_lengths

        return fast_path_lengths(scene, supersample=supersample, keep_hits=keep_hits)

    def __repr__(self) -> str:
        return "FastEngine()"


#: The engines by name. Each is an :class:`Engine`; calling one,
#: ``ENGINES[name](scene, *, supersample, keep_hits) -> (L, hits or None)``, gives the path
#: lengths ``(W * H * supersample**2, n_bodies)`` of the rays of
#: :func:`~xray_viz.geometry.detector_rays` ``(scene, supersample=supersample)``, in that order.
ENGINES = {"fast": FastEngine(), "numpy": NumpyEngine()}
