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

A :class:`Projector` is the first stage of the pipeline (``ARCHITECTURE.md``): bodies and an
engine, built once, asked for the path lengths of any acquisition
(``projector.path_lengths(acquisition)``); the engine's capabilities (hits, kept results,
compiled kernels, working memory) are its attributes, so nothing outside this module tests an
engine's name.

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
>>> projector = Projector(scene.bodies, engine="numpy")
>>> bool((projector.path_lengths(scene.acquisition) == L).all()), projector.returns_hits
(True, True)
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from xray_viz.geometry import check_supersample
from xray_viz.tracing import reference

__all__ = ["Engine", "NumpyEngine", "FastEngine", "ENGINES", "DEFAULT_ENGINE", "Projector"]


class Engine(Protocol):
    """What a rendering engine provides.

    Attributes
    ----------
    name : str
        Its key in :data:`ENGINES` (``--engine`` on the command line).
    returns_hits : bool
        Whether :meth:`hits` can return every hit of every ray.
    keeps_results : bool
        Whether :meth:`path_lengths` of a whole frame keeps its result on the bodies (a frame
        that fits in one band is then best traced whole).
    compiled : bool
        Whether its kernels are compiled (numba) on first use, and cached on disk.
    ray_bytes : int
        Working memory per ray of a window besides its path lengths (rays, hits, the sweep's
        temporaries), for choosing the windows.
    fallback : str
        The other engine, which may trace a scene this one fails on.
    """

    name: str
    returns_hits: bool
    keeps_results: bool
    compiled: bool
    ray_bytes: int
    fallback: str

    def path_lengths(self, bodies, acquisition, *, supersample: int = 1) -> np.ndarray:
        """``(W * H * supersample**2, n_bodies)`` float: every detector ray's path lengths."""

    def windows(self, bodies, acquisition, *, supersample: int = 1, rows: int | None = None):
        """Yield ``(r0, r1, L)``: the path lengths of image rows ``r0 .. r1 - 1`` (windows of
        about ``rows`` rows, from the top), bit for bit those of :meth:`path_lengths`."""

    def __call__(self, scene, *, supersample: int = 1, keep_hits: bool = False):
        """``(L, hits or None)`` of a scene (``keep_hits``: every hit, where supported); a
        public adapter over ``path_lengths`` and ``hits``."""


class NumpyEngine:
    """The pure-NumPy reference engine (watertight Moller-Trumbore on culled ray-triangle
    pairs, every hit swept in order of ``t``)."""

    name = "numpy"
    returns_hits = True
    keeps_results = False
    compiled = False
    ray_bytes = 2048
    fallback = "fast"

    def path_lengths(self, bodies, acquisition, *, supersample: int = 1) -> np.ndarray:
        """Path lengths of every detector ray (see :class:`Engine`)."""
        n = check_supersample(supersample)
        return reference._path_lengths(bodies, acquisition, supersample=n)[0]

    def hits(self, bodies, acquisition, *, supersample: int = 1, rows=None):
        """``(L, hits)``: path lengths and every hit (:class:`~xray_viz.tracing.hits.Hits`,
        ray numbers within ``rows``)."""
        n = check_supersample(supersample)
        return reference._path_lengths(bodies, acquisition, supersample=n, keep_hits=True,
                                       rows=rows)

    def windows(self, bodies, acquisition, *, supersample: int = 1, rows: int | None = None):
        """Path lengths window by window of image rows (see :class:`Engine`)."""
        n = check_supersample(supersample)
        yield from reference._rows(bodies, acquisition, supersample=n, rows=rows)

    def __call__(self, scene, *, supersample: int = 1, keep_hits: bool = False):
        """``(L, hits or None)`` of a scene (see :class:`Engine`; a public adapter)."""
        n = check_supersample(supersample)
        return reference._path_lengths(scene.bodies, scene.acquisition, supersample=n,
                                       keep_hits=keep_hits)

    def __repr__(self) -> str:
        return "NumpyEngine()"


class FastEngine:
    """The fast engine (:mod:`xray_viz.tracing.fast`): a watertight fixed-point footprint
    rasteriser in numba. Recent results of small detectors are kept on the bodies per
    acquisition, so re-rendering the same geometry with other energies or materials costs
    nothing."""

    name = "fast"
    returns_hits = False
    keeps_results = True
    compiled = True
    ray_bytes = 0
    fallback = "numpy"

    def path_lengths(self, bodies, acquisition, *, supersample: int = 1) -> np.ndarray:
        """Path lengths of every detector ray (see :class:`Engine`); read-only when kept."""
        from xray_viz.tracing.fast import _path_lengths

        return _path_lengths(bodies, acquisition, supersample=supersample)[0]

    def windows(self, bodies, acquisition, *, supersample: int = 1, rows: int | None = None):
        """Path lengths window by window of image rows (see :class:`Engine`)."""
        from xray_viz.tracing.fast import _rows

        yield from _rows(bodies, acquisition, supersample=supersample, rows=rows)

    def __call__(self, scene, *, supersample: int = 1, keep_hits: bool = False):
        """``(L, hits or None)`` of a scene; ``keep_hits`` asks the NumPy engine for the hits
        (a public adapter)."""
        from xray_viz.tracing.fast import _path_lengths

        return _path_lengths(scene.bodies, scene.acquisition, supersample=supersample,
                             keep_hits=keep_hits)

    def __repr__(self) -> str:
        return "FastEngine()"


#: The engines by name. Each is an :class:`Engine`; calling one,
#: ``ENGINES[name](scene, *, supersample, keep_hits) -> (L, hits or None)``, gives the path
#: lengths ``(W * H * supersample**2, n_bodies)`` of the rays of
#: :func:`~xray_viz.geometry.detector_rays` ``(scene, supersample=supersample)``, in that order.
ENGINES = {"fast": FastEngine(), "numpy": NumpyEngine()}

#: The engine a :class:`Projector` uses unless told otherwise: the compiled fast engine.
DEFAULT_ENGINE = "fast"

#: The engine that gives every hit (:meth:`Projector.hits`, whatever the projector's engine).
_HITS = ENGINES["numpy"]


class Projector:
    """Bodies and an engine: the path lengths of the bodies at any acquisition.

    Built once per bodies (a scan, a render loop or an optimiser reuses it for every pose);
    what the engine derives from the meshes stays on the :class:`~xray_viz.bodies.Bodies`
    (:meth:`~xray_viz.bodies.Bodies.cached`), so two projectors of the same bodies share it.

    Parameters
    ----------
    bodies : Bodies
    engine : str
        A key of :data:`ENGINES`: ``"fast"`` (default) or ``"numpy"``.

    Attributes
    ----------
    bodies : Bodies
    engine : Engine
    name, returns_hits, keeps_results, compiled, ray_bytes, fallback
        The engine's (see :class:`Engine`).
    hits_ray_bytes : int
        Working memory per ray of a window of ``hits`` (the engine that gives the hits).

    Raises
    ------
    SceneError
        For an unknown engine name.
    """

    def __init__(self, bodies, engine: str = DEFAULT_ENGINE):
        if not isinstance(engine, str) or engine not in ENGINES:
            from xray_viz.errors import SceneError

            raise SceneError(f"unknown engine {engine!r}; choose one of {', '.join(ENGINES)}")
        self.bodies = bodies
        self.engine = ENGINES[engine]

    name = property(lambda self: self.engine.name, doc="The engine's name.")
    returns_hits = property(lambda self: self.engine.returns_hits,
                            doc="Whether the engine itself gives every hit.")
    keeps_results = property(lambda self: self.engine.keeps_results,
                             doc="Whether whole frames are kept on the bodies.")
    compiled = property(lambda self: self.engine.compiled,
                        doc="Whether the engine's kernels are compiled on first use.")
    ray_bytes = property(lambda self: self.engine.ray_bytes,
                         doc="Working memory per ray of a window besides its path lengths.")
    fallback = property(lambda self: self.engine.fallback,
                        doc="The other engine, for a scene this one fails on.")
    hits_ray_bytes = property(lambda self: _HITS.ray_bytes,
                              doc="Working memory per ray of a window of ``hits``.")
    columns = property(lambda self: len(self.bodies),
                       doc="The path lengths' columns per ray: one per body.")

    def path_lengths(self, acquisition, *, supersample: int = 1) -> np.ndarray:
        """``(W * H * supersample**2, n_bodies)`` float: every detector ray's path lengths
        (:func:`~xray_viz.geometry.detector_rays` order; read-only when kept)."""
        return self.engine.path_lengths(self.bodies, acquisition, supersample=supersample)

    def windows(self, acquisition, *, supersample: int = 1, rows: int | None = None):
        """Yield ``(r0, r1, L)``: the path lengths of image rows ``r0 .. r1 - 1`` (windows of
        about ``rows`` rows, from the top), bit for bit those of :meth:`path_lengths`."""
        return self.engine.windows(self.bodies, acquisition, supersample=supersample, rows=rows)

    def hits(self, acquisition, *, supersample: int = 1):
        """``(L, hits)``: the path lengths and every hit of every ray, from the NumPy engine
        whatever this projector's engine (the fast engine builds no hit list)."""
        return _HITS.hits(self.bodies, acquisition, supersample=supersample)

    def __repr__(self) -> str:
        return f"Projector({len(self.bodies)} bodies, engine={self.name!r})"
