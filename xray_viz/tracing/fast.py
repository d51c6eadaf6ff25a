"""The fast engine: a watertight fixed-point footprint rasteriser (numba).

For a detector grid every ray shares the source (point source) or the direction (parallel
beam), so tracing all hits is rasterising the scene's triangles onto the detector:

0. **Cull bodies**: a body whose bounding box (kept by the bodies) lies wholly outside the beam -
   outside one side plane of the pyramid from a point source through the detector's edges
   (widened by a pixel), or of a parallel beam's slab box, wholly behind the plane of the
   source or beyond the detector - is skipped as a whole: none of its vertices is projected,
   its path lengths are zero, and precedence among the other bodies is unchanged (no ray
   meets it, so it contains no stretch of any ray).
1. **Project** each mesh vertex onto the detector (perspective for a point source, orthographic
   for a parallel beam) in units of the ray grid (with ``n x n`` supersampling, the sub-ray grid),
   and **snap** it to fixed point, ``2**-22`` of a grid step (``FRAC_BITS``). Shared vertices
   snap identically.
2. **Footprint only**: each triangle visits the rays inside its snapped bounding box (clipped to
   the detector); triangles outside the beam, behind the source or beyond the detector are culled.
3. **Exact coverage**: three int64 edge functions per ray; a ray exactly on an edge or vertex
   is resolved by a tie rule (the ray is moved by an infinitesimal ``(eps, eps * delta)``), so a
   ray through a shared edge or vertex belongs to exactly one triangle of each surface sheet, on
   every configuration, by construction. Projected triangles larger than 256 grid steps use
   exact limb arithmetic instead of int64.
4. **Depth** of a covered ray: the exact ray-plane intersection in float64, from the unsnapped
   vertices, clamped to the triangle's depth range. The sign of the projected area tells entry
   (counter-clockwise seen from the source) from exit.
5. **Path lengths**: one body in the beam whose winding number is provably 0 or 1 (one
   edge-connected piece, or outward pieces with disjoint bounding boxes:
   :attr:`xray_viz.bodies.Bodies.simple`, from the mesh reports):
   ``L = sum(exit depths) - sum(entry depths)`` (+ the detector depth when the ray is still
   inside there), accumulated per ray in one parallel pass over the triangles (one accumulator
   per thread; per band of rows for very large detectors, and when the body reaches beyond
   the detector plane, where the crossings it drops are counted); no hit list. Otherwise (several
   bodies, or one body of overlapping, nested or hollow pieces): per band of detector rows,
   the hits of each ray are counted, stored, sorted and swept with the reference semantics of
   :func:`xray_viz.attenuation.path_lengths`: a body contains the stretches of ray where the
   winding number of its surface is positive (the nonzero rule: overlapping pieces give
   their union, an inward piece inside an outward one a cavity), and the highest precedence
   among the bodies containing a stretch wins. Memory is O(triangles + rays + hits of one
   band).

6. **Windows** (:func:`trace_rows`, used by :func:`xray_viz.render`): after the set-up above
   (done once), the bands are rastered a window of whole pixel rows at a time, into path
   lengths of that window's rays only, so a big job needs O(meshes + one window) memory, not
   O(rays x bodies). A ray's result does not depend on the windows (bit for bit).

What the engine derives from the meshes is kept on the scene's
:class:`~xray_viz.bodies.Bodies` (:meth:`~xray_viz.bodies.Bodies.cached`), never in this
module: the per-mesh set-up (faces sorted along the Morton order of their vertices, vertices
numbered in order of first use by those faces), its concatenation over the bodies in the beam,
scratch memory, and the results of :func:`fast_path_lengths` for the last few acquisitions
when they are small (64 MiB at most, 128 MiB in all): re-rendering the same geometry with other
energies or materials costs nothing, and a new acquisition (the source moved) pays no per-mesh
set-up again. The kernels write every ray of a result, so the memory of the last result (up to
64 MiB), or of one the result cache has dropped, is handed to the next call on the same bodies
once nothing else holds it (:func:`_result_buffer`, :func:`_offer_buffer`): a frame does not
pay the page faults of a fresh array.

Limits: meshes must be closed and outward oriented (as for the NumPy engine). A body crossing
the plane of the source inside the beam cannot be projected and is refused with a
:class:`~xray_viz.errors.SceneError` (the NumPy engine traces it): precisely, a triangle that
crosses that plane is refused unless it lies wholly outside one side plane of the beam (then no
ray meets it and it is skipped), so a body crossing the source plane away from the beam renders.
Snapping moves projected vertices by at most ``2**-23`` of a grid step: the watertightness is
exact, and the path length of a ray grazing a silhouette within that distance differs from the
exact one by the chord there (below 1e-9 of the body size in the stress suite).

Precision: float64 throughout (projection, depths, sums) and exact int64 / limb arithmetic for
coverage. **There is no float32 path** in this engine or in the NumPy engine, so there is no
float32-against-float64 error to report; the stress suite (``tests/tracing/test_stress.py``) measures
the float64 engines against exact rational references instead.

Rays are the ideal grid of :func:`xray_viz.geometry.detector_rays`; the engine agrees with the
NumPy reference engine to rounding (~1e-12 relative) except on rays lying *in* a face plane,
whose length is ambiguous (either one-sided limit is correct).
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import threading

import numba
import numpy as np

from xray_viz.errors import SceneError
from xray_viz.geometry import check_supersample
from xray_viz.tracing._raster import ERR_STRADDLE, FRAC_BITS

__all__ = ["fast_path_lengths", "trace_once", "trace_rows", "clear_caches", "visible_bodies",
           "FRAC_BITS"]

#: Results larger than this are not kept (render() traces them window by window anyway), and
#: a scene's bodies keep at most ``_RESULT_BYTES`` of results in all (4 at most): a bounded,
#: predictable memory.
_RESULT_ENTRY_BYTES = 64 << 20
_RESULT_BYTES = 128 << 20
_RESULTS = 4
#: Per-mesh set-ups (spatial order) and concatenations of the bodies in the beam kept per
#: scene's bodies, bounded in bytes (a body set of a few big meshes keeps a few).
_GEOMETRY_BYTES = 512 << 20


def clear_caches(scene) -> None:
    """Forget what the fast engine keeps on a scene's bodies (its per-mesh set-up, scratch
    memory and recent results), for timing cold runs. A public adapter: a scene gives its
    bodies.

    Parameters
    ----------
    scene : Scene or Bodies
    """
    bodies = getattr(scene, "bodies", scene)
    bodies.forget(("fast", "prepared"))
    bodies.forget(("fast", "geometry"))
    bodies.forget(("fast", "result"))
    bodies.forget(("fast", "workspace"))
    bodies.forget(("fast", "accumulators"))
    bodies.forget(("fast", "result buffer"))


def _spatial_order(v, f):
    """Faces sorted along the Morton (Z-curve) order of their first vertex, and vertices
    numbered in order of first use by those faces, so that the per-call passes over triangles
    and vertices touch memory nearly in sequence (``benchmarks/notes/kernels.md``); the vertices
    coordinate-major, ``(3, n)`` (the kernels' layout; small meshes keep their order). Projection
    independent: done once per mesh, in compiled code (:func:`xray_viz.tracing._raster_calls.
    spatial_order`: a radix sort of the vertices' Morton codes, a counting sort of the faces)."""
    if len(v) < 4096 or len(v) >= 2**31:
        return np.ascontiguousarray(v.T), f
    from xray_viz.tracing._raster_calls import spatial_order

    return spatial_order(v, f)


def _prepared(bodies, k):
    """Body ``k``'s vertices (3, V) float64 (coordinate-major) and faces (T, 3) int32/int64 in
    spatial order (:func:`_spatial_order`), kept by the bodies."""
    def build():
        body = bodies[k]
        v, f = _spatial_order(np.asarray(body.vertices, dtype=np.float64),
                              np.asarray(body.faces, dtype=np.int64))
        f = np.asarray(f, dtype=np.int32 if len(v) < 2**31 else np.int64, order="C")
        if np.may_share_memory(v, body.mesh.vertices):
            v = v.copy()                # small meshes: not a view of the mesh's own data
        if np.may_share_memory(f, body.mesh.faces):
            f = f.copy()
        for a in (v, f):
            a.setflags(write=False)
        return v, f
    return bodies.cached(("fast", "prepared", k), build, limit=max(8, len(bodies)),
                         nbytes=_GEOMETRY_BYTES)


def _geometry(bodies, keep=None):
    """Concatenated vertices (3, V) float64 (coordinate-major), faces (T, 3) int32 (int64 beyond
    2**31 vertices) and triangle bodies (T,) int32 (indices into ``bodies``) of the bodies
    ``keep`` (default: all), kept by the bodies per tuple ``keep``."""
    keep = tuple(range(len(bodies))) if keep is None else tuple(keep)

    def build():
        parts = [_prepared(bodies, k) for k in keep]
        if len(parts) == 1:
            V, F = parts[0]             # shared with the per-mesh set-up: no copy
        elif parts:
            offset = np.cumsum([0] + [v.shape[1] for v, _ in parts])
            wide = offset[-1] >= 2**31
            V = np.ascontiguousarray(np.concatenate([v for v, _ in parts], axis=1))
            F = np.ascontiguousarray(np.concatenate(
                [f.astype(np.int64) + o for (_, f), o in zip(parts, offset)]),
                dtype=np.int64 if wide else np.int32)
        else:
            V, F = np.zeros((3, 0)), np.zeros((0, 3), np.int32)
        B = np.concatenate([np.full(len(f), k, np.int32) for k, (_, f) in zip(keep, parts)]) \
            if parts else np.zeros(0, np.int32)
        for a in (V, F, B):
            a.setflags(write=False)
        return V, F, B
    return bodies.cached(("fast", "geometry", keep), build, limit=8,
                         nbytes=_GEOMETRY_BYTES)


def visible_bodies(scene, planes=None) -> tuple:
    """Indices of the bodies whose bounding box meets the beam (any supersampling); the others
    are culled as a whole: no vertex of theirs is projected, their path lengths are zero.

    A public adapter: the scene's bodies and acquisition go to the function the engine uses.

    Boxes are kept by the scene's bodies (:attr:`xray_viz.bodies.Bodies.bounds`). A body is
    culled when its box lies wholly outside one side plane of the beam (the pyramid from a
    point source through the detector's edges, the slab box of a parallel beam), wholly behind
    the plane of the source or wholly beyond the detector
    (:meth:`xray_viz.geometry.Acquisition.outside_beam`).
    """
    return _visible(scene.bodies, scene.acquisition, planes)


def _visible(bodies, acq, planes=None) -> tuple:
    """:func:`visible_bodies` of ``bodies`` seen by the acquisition ``acq``."""
    if not len(bodies):
        return ()
    if planes is None:
        out = acq.outside_beam(bodies.bounds)
    else:
        from xray_viz.geometry import boxes_outside_beam

        out = boxes_outside_beam(bodies.bounds[:, 0], bodies.bounds[:, 1], acq.frame.source,
                                 planes)
    return tuple(int(k) for k in np.flatnonzero(~out))


_LOCK = threading.RLock()     # one trace at a time: numba's parallel kernels, shared scratch


@contextlib.contextmanager
def _locked(bodies):
    """``_LOCK`` held, and the bodies' meshes taken as unchanged once checked on entry
    (:meth:`xray_viz.bodies.Bodies.checked`): a frame's dozen lookups of the bodies' derived
    data hash each mesh once."""
    with _LOCK, bodies.checked():
        yield


def _workspace(bodies, n_vertices, n_triangles):
    """Scratch arrays reused between calls on the same bodies (fresh pages cost more than
    the projection)."""
    return bodies.cached(("fast", "workspace", n_vertices, n_triangles), lambda: (
        np.empty((n_vertices, 2), np.int64), np.empty(n_vertices),
        np.empty(n_vertices, np.bool_), np.empty(n_triangles, np.int8),
        np.empty((n_triangles, 4), np.int64), np.empty(n_vertices, np.int32)), limit=1)


def _refs(box) -> int:
    """How many references to ``box[0]`` :func:`sys.getrefcount` sees from here."""
    return sys.getrefcount(box[0])


#: What :func:`_refs` gives for an object that only its box holds (measured the same way, so
#: whatever references the interpreter borrows or takes for the call do not matter).
_BOX_ONLY = _refs([object()])


def _result_buffer(bodies, n_rays, nb):
    """An ``(n_rays, nb)`` float64 array for a window's path lengths, *not* zeroed: the
    kernels that fill it write every ray (the several-bodies raster zeroes each band's rays
    before it adds the band's lengths; :func:`~xray_viz.tracing._raster._finish` writes every
    ray of its rows).

    The array the last call on these bodies returned, if nothing else holds it any more (not
    the caller, a view of it, nor the result cache): the first touch of a fresh result costs
    page faults every frame (``benchmarks/notes/kernels.md``). Else a new array,
    kept for the next call. Results above 64 MiB are not kept (a dead buffer of that size
    held between frames is memory the caller did not ask for). Called under ``_LOCK``."""
    if n_rays * nb * 8 > _RESULT_ENTRY_BYTES:
        return np.empty((n_rays, nb))
    box = _buffer_box(bodies, (n_rays, nb))
    if box[0] is not None and _refs(box) == _BOX_ONLY:
        box[0].setflags(write=True)         # it may have been a cached read-only result
        return box[0]
    box[0] = np.empty((n_rays, nb))
    return box[0]


def _buffer_box(bodies, shape):
    """The one-element list holding the buffer of :func:`_result_buffer` for ``shape`` (one
    shape kept per bodies)."""
    return bodies.cached(("fast", "result buffer") + tuple(shape), lambda: [None], limit=1)


def _offer_buffer(bodies, old):
    """A result the result cache dropped (an array :func:`trace_once` made), kept for
    :func:`_result_buffer` to hand to the next call of its shape (it does so only once nothing
    else holds it), unless the buffer kept for that shape is free already: a render loop's
    frames then reuse the memory of the results they push out of the cache."""
    with _LOCK:         # as _result_buffer, which runs under it: never between its look and use
        box = _buffer_box(bodies, old.shape)
        if box[0] is None or _refs(box) != _BOX_ONLY:
            box[0] = old


#: Above this many (threads x samples), one body is traced by bands (memory) not per thread.
_DIRECT_MAX_SAMPLES = 1 << 23


#: How to fall back to the reference engine, for the refusal messages.
_USE_NUMPY = "use the NumPy engine (engine='numpy' in Python, --engine numpy on the command line)"


def _refuse(bodies, acq, B, t, r0, w, F):
    body = bodies[int(B[t])].name
    ws = w[F[t]]
    perspective = not acq.parallel
    if ws.min() < 0 or (perspective and ws.min() <= 0):
        raise SceneError(
            f"body {body!r} crosses the plane of the source (through {r0.tolist()}, across the "
            f"beam) within the beam's cone: the fast engine cannot project it; move the source "
            f"back or {_USE_NUMPY}")
    raise SceneError(
        f"body {body!r} is too close to the plane of the source to project onto the detector; "
        f"move the source back or {_USE_NUMPY}")


def _accumulators(bodies, n_chunks, nH, nW):
    """Zeroed per-thread depth sums, reused between calls on the same bodies (no fresh
    pages to fault in); each thread's is zeroed on a thread of the pool (NumPy's fill
    releases the GIL, so two threads zero faster than one in turn; zeroing in the raster
    kernel would lengthen its compile; ``benchmarks/notes/kernels.md``)."""
    from xray_viz._threads import run_pieces

    fresh = []
    S = bodies.cached(("fast", "accumulators", n_chunks, nH, nW), lambda: fresh.append(1) or
                      np.zeros((n_chunks, nH, nW)), limit=1)
    if not fresh:
        run_pieces(lambda c: S[c].fill(0), n_chunks)
    return S


def _band_order(entries):
    """Bands ``0 .. len(entries) - 1`` longest first: the order in which the threads take
    them, each the next one when it is free (:func:`~xray_viz.tracing._raster._claim`), a
    greedy list schedule. A band's work is its triangle entries plus 200 (its own rays): its
    raster time follows its entries (correlation 0.998 over the frog's 32 bands, which hold 0
    to 25k entries each). Taken so, the threads end within about one band of each other
    whatever their speed (a late or slowed thread takes fewer), where bands dealt out before
    the start left one thread idle at the end of a frame. Deterministic,
    and the results do not depend on it (each band writes its own rays).

    Examples
    --------
    >>> _band_order(np.array([5, 900, 40, 1000, 0])).tolist()
    [3, 1, 2, 0, 4]
    """
    return np.argsort(-(np.asarray(entries, np.int64) + 200), kind="stable")


def fast_path_lengths(scene, *, supersample: int = 1, keep_hits: bool = False, cache: bool = True):
    """Effective path lengths of the detector rays through every body (engine ``"fast"``).

    A public adapter: the scene's bodies and acquisition go to the function the engines use.

    Parameters
    ----------
    scene : Scene
        Source, detector and bodies (closed, outward-oriented meshes).
    supersample : int, optional
        ``n x n`` rays per pixel, in the order of :func:`xray_viz.geometry.detector_rays`.
    keep_hits : bool, optional
        The fast engine never builds a hit list; ``True`` delegates to the NumPy engine, which
        returns one.
    cache : bool, optional
        Reuse the result of an earlier call on the same bodies (or bodies of the same mesh
        objects), source, detector and supersampling (the default); it is kept on the bodies.
        The returned array is then shared and read-only. Only results of at most 64 MiB are
        kept (at most 128 MiB in all, 4 results); larger ones are returned writable and not
        kept. The memory of a result the cache drops goes to a later call of the same shape
        once nothing else holds it (a render loop's frames pay no fresh pages).

    Returns
    -------
    L : (W * H * supersample**2, n_bodies) float
        Millimetres of each ray in each body's material.
    hits : None
        (or the NumPy engine's hits with ``keep_hits=True``).

    Raises
    ------
    SceneError
        If a triangle straddles the plane of the source (it cannot be projected), or sits so
        close to it that its projection overflows the fixed-point grid.

    Examples
    --------
    >>> import xray_viz
    >>> L, _ = fast_path_lengths(xray_viz.load_scene("sphere"))
    >>> L.shape, round(float(L.max()), 1)
    ((65536, 1), 80.0)
    """
    return _path_lengths(scene.bodies, scene.acquisition, supersample=supersample,
                         keep_hits=keep_hits, cache=cache)


def _path_lengths(bodies, acq, *, supersample=1, keep_hits=False, cache=True):
    """:func:`fast_path_lengths` of ``bodies`` seen by the acquisition ``acq``."""
    n = check_supersample(supersample)
    W, H = acq.detector.shape
    if keep_hits or (n > 1 and (W == 1 or H == 1)):
        from xray_viz.tracing.reference import _path_lengths as numpy_path_lengths

        return numpy_path_lengths(bodies, acq, supersample=n, keep_hits=keep_hits)
    key = ("fast", "result", acq.key, n)
    if cache:
        hit = bodies.lookup(key)
        if hit is not None:
            return hit, None
    L = _trace(bodies, acq, supersample=n)
    if cache and L.nbytes <= _RESULT_ENTRY_BYTES:
        L.setflags(write=False)
        bodies.store(key, L, limit=_RESULTS, nbytes=_RESULT_BYTES,
                     on_evict=lambda old: _offer_buffer(bodies, old))
    return L, None


def trace_once(scene, *, supersample: int = 1) -> np.ndarray:
    """Trace a scene's detector rays with the fast engine, without the result cache.

    A public adapter: the scene's bodies and acquisition go to the function the engines use.

    Parameters
    ----------
    scene : Scene
    supersample : int, optional

    Returns
    -------
    (W * H * supersample**2, n_bodies) float
        Effective path lengths (mm), rays in the order of
        :func:`~xray_viz.geometry.detector_rays`.
    """
    return _trace(scene.bodies, scene.acquisition, supersample=supersample)


def _trace(bodies, acq, *, supersample):
    """:func:`trace_once` of ``bodies`` seen by the acquisition ``acq``."""
    n = check_supersample(supersample)
    with _locked(bodies):
        plan = _Plan(bodies, acq, n, None)
        return plan.window(0, plan.n_bands)[2]


def trace_rows(scene, *, supersample: int = 1, rows: int | None = None):
    """Trace a scene's detector rays with the fast engine window by window of image rows.

    A public adapter: the scene's bodies and acquisition go to the function the engines use.

    The per-scene set-up (culling, projection, triangle set-up and binning) is done once; then
    each window of about ``rows`` image rows is rastered on its own, so memory is O(meshes +
    rays of one window x bodies) instead of O(rays x bodies). Windows are whole pixel rows and
    whole bands of the banded rasters; every ray's path lengths are exactly (bit for bit) those
    of :func:`trace_once`, whatever the windows.

    Parameters
    ----------
    scene : Scene
    supersample : int, optional
    rows : int, optional
        Image rows per window, at least 1 (default: the whole detector, one window). Windows
        are rounded to whole bands of the raster, so they may hold a few rows less.

    Yields
    ------
    r0, r1 : int
        The window's image rows ``r0 .. r1 - 1`` (row 0 at the top), from the top down.
    L : (W * (r1 - r0) * supersample**2, n_bodies) float
        Path lengths (mm) of rays ``r0 * W * n * n`` up to ``r1 * W * n * n`` of
        :func:`~xray_viz.geometry.detector_rays`.

    Examples
    --------
    >>> import numpy as np, xray_viz
    >>> scene = xray_viz.load_scene("sphere")
    >>> parts = list(trace_rows(scene, rows=100))
    >>> parts[0][0], parts[-1][1], all(0 < r1 - r0 <= 100 for r0, r1, _ in parts)
    (0, 256, True)
    >>> bool(np.array_equal(np.concatenate([L for *_, L in parts]), trace_once(scene)))
    True
    """
    return _rows(scene.bodies, scene.acquisition, supersample=supersample, rows=rows)


def _rows(bodies, acq, *, supersample=1, rows=None):
    """:func:`trace_rows` of ``bodies`` seen by the acquisition ``acq``."""
    n = check_supersample(supersample)
    W, H = acq.detector.shape
    if n > 1 and (W == 1 or H == 1):       # as fast_path_lengths: the NumPy engine's rays
        from xray_viz.tracing.reference import _rows as numpy_rows

        yield from numpy_rows(bodies, acq, supersample=n, rows=rows)
        return
    window = None if rows is None or rows >= H else n * max(1, int(rows))
    with _locked(bodies):
        plan = _Plan(bodies, acq, n, window)
        if plan.per_window >= plan.n_bands:         # one window: done under this lock
            part = plan.window(0, plan.n_bands)
        else:
            plan.detach()
    if plan.per_window >= plan.n_bands:
        yield part
        return
    # Windows from the top of the image down: the bands from the last one down.
    for b1 in range(plan.n_bands, 0, -plan.per_window):
        with _locked(bodies):
            part = plan.window(max(0, b1 - plan.per_window), b1)
        yield part


#: Fine-grid samples in one band of the banded rasters at most: bounds the hit buffers of
#: a band (counts, offsets and every hit of its samples), of which each thread has one.
_BAND_SAMPLES = 1 << 20


def _band_height(nH, nW, n, window):
    """Fine rows per band: a multiple of ``n`` (bands are whole pixel rows), at most
    :data:`_BAND_SAMPLES` samples, and with a window of ``window`` fine rows, small enough to
    give each thread two bands of a window."""
    n_bands = int(min(nH, max(2, 16 * (os.cpu_count() or 2))))
    bh = int(math.ceil(nH / n_bands))
    bh = min(bh, max(1, _BAND_SAMPLES // max(nW, 1)))
    if window is not None:
        bh = min(bh, max(1, window // (2 * numba.get_num_threads())))
    return n * max(1, bh // n)


class _Plan:
    """The fast engine's per-scene set-up, then path lengths window by window of bands.

    Construct and call :meth:`window` under ``_LOCK`` (the scratch arrays are shared); after
    :meth:`detach` the plan holds its own copies of them and only the kernels need the lock.
    """

    def __init__(self, bodies, acq, n, window):
        from xray_viz.tracing import _raster_calls as R

        self.R = R
        self.bodies = bodies
        self.n = n
        W, H = self.shape = acq.detector.shape
        self.nb = nb = len(bodies)
        nW, nH = self.nW, self.nH = W * n, H * n
        self.band_height = bh = _band_height(nH, nW, n, window)
        self.n_bands = int(math.ceil(nH / bh))
        self.per_window = self.n_bands if window is None else max(1, window // bh)
        self.mode = "empty"
        if nb == 0:
            return
        # The frame of the projection (geometry.DetectorFrame, FineGrid): depths along
        # depth_axis (the detector at depth FL), the projection's linear parts eu, ev, the
        # principal point (bx, by); f is a parallel beam's ray direction.
        fr, g = acq.frame, acq.frame.grid(n)
        r0, f, FL, depth_axis = fr.source, fr.forward, fr.depth, fr.depth_axis
        eu, ev = fr.project_u, fr.project_v
        sx, sy, bx, by, Ex, Ey, P0 = g.sx, g.sy, g.bx, g.by, g.ex, g.ey, g.q00
        planes = acq.planes
        keep = self.keep = _visible(bodies, acq)
        if not keep:
            return
        V, F, B = _geometry(bodies, keep)
        if len(F) == 0:
            return
        sides = np.ascontiguousarray(planes[:4])
        perspective = not fr.parallel
        XY, w, huge, status, box, K = _workspace(bodies, V.shape[1], len(F))
        if perspective:
            wmin, wmax, odd = R.project_vertices(V, r0, depth_axis, eu, ev, sx * FL, bx,
                                                 sy * FL, by, True, XY, w, huge, nW, nH, K)
        else:
            wmin, wmax, odd = R.project_vertices(V, r0, depth_axis, eu, ev, sx, bx, sy, by,
                                                 False, XY, w, huge, nW, nH, K)
        self.FL, self.perspective, self.P0, self.Ex, self.Ey = FL, perspective, P0, Ex, Ey
        self.F, self.XY, self.B, self.V, self.w, self.r0, self.f = F, XY, B, V, w, r0, f
        n_chunks = numba.get_num_threads()
        # every vertex strictly between the source and detector planes, none huge: no triangle
        # can be refused, and cell codes may cull (the rasters' first pass)
        depth_ok = bool(wmin > 0 and wmax < FL and not odd)
        # The signed depth sum is a body's path length only where its winding number is 0 or 1
        # (from the mesh reports the bodies keep).
        if len(keep) == 1 and bodies.simple[keep[0]]:
            if n_chunks * nH * nW <= _DIRECT_MAX_SAMPLES and wmax <= FL:
                # A single pass over the triangles, one accumulator per thread: the depth
                # spans S of every sample now (O(samples), at most _DIRECT_MAX_SAMPLES). A
                # body beyond the detector plane takes the bands, which count the crossings
                # that end rays at the detector.
                self.mode = "direct"
                Sc = _accumulators(bodies, n_chunks, nH, nW)
                err = np.empty(n_chunks, np.int64)
                R.raster_direct(n_chunks, F, XY, w, huge, V, perspective, r0, P0, Ex, Ey, f, FL,
                                nW, nH, depth_ok, Sc, err, K, sides)
                if err.max() >= 0:
                    _refuse(bodies, acq, B, int(err.max()), r0, w, F)
                # The accumulators are summed where they are read (window), or into S when
                # the plan outlives the lock (detach).
                self.Sc, self.S = Sc, None
                return
            self.mode = "single"
        else:
            self.mode = "multi"
            self.prec = np.ascontiguousarray(bodies.precedence, dtype=np.int64)
        self.status, self.box = status, box
        self.band_start, self.band_tris = _setup(R, F, XY, w, huge, V, perspective, r0, FL, nW,
                                                 nH, sides, status, box, B, (bodies, acq), bh, K,
                                                 depth_ok)

    def detach(self):
        """Own copies of the shared scratch arrays still needed by :meth:`window`."""
        if self.mode in ("single", "multi"):
            self.XY, self.w, self.status, self.box = (
                a.copy() for a in (self.XY, self.w, self.status, self.box))
        elif self.mode == "direct" and self.S is None:
            self.S = np.empty((self.nH, self.nW))
            self.R.reduce_chunks(self.Sc, None, self.FL, self.S)
            self.Sc = None

    def _bands(self):
        """The per-triangle arguments of the banded rasters after ``band_height, nH, nW``."""
        return (self.status, self.box, self.F, self.XY, self.V, self.w, self.r0, self.f, self.B,
                self.FL)

    def _order(self, b0, b1):
        """Bands ``b0 .. b1 - 1``, in the order the threads take them (:func:`_band_order`)."""
        entries = np.diff(self.band_start[:, b0:b1 + 1], axis=1).sum(axis=0)   # over pieces
        return _band_order(entries) + b0

    def window(self, b0, b1):
        """``(r0, r1, L)``: path lengths of the image rows of bands ``b0 .. b1 - 1``."""
        R, n = self.R, self.n
        W, H = self.shape
        bh, nH, nW = self.band_height, self.nH, self.nW
        y0, y1 = b0 * bh, min(nH, b1 * bh)             # fine rows (Y up), whole pixel rows
        r0, r1 = H - y1 // n, H - y0 // n              # image rows (row 0 at the top)
        ray0 = r0 * W * n * n
        n_rays = (r1 - r0) * W * n * n
        if self.mode == "empty":
            return r0, r1, np.zeros((n_rays, self.nb))
        args = (self.FL, self.perspective, self.P0, self.Ex, self.Ey, n, W, H)
        if self.mode == "multi":
            L = _result_buffer(self.bodies, n_rays, self.nb)
            R.raster_multi(self._order(b0, b1), self.band_start, self.band_tris, bh, nH, nW,
                           *self._bands(), self.prec, *args[1:], L, ray0)
            return r0, r1, L
        if self.nb == 1:                 # the finish writes every ray of the window's rows
            L = L1 = _result_buffer(self.bodies, n_rays, 1)
        else:                            # one body of several in the beam: the others' are 0
            L, L1 = np.zeros((n_rays, self.nb)), np.zeros((n_rays, 1))
        if self.mode == "direct" and self.S is None:
            R.finish_chunks(self.Sc, *args, L1, y0, y1, ray0)
        elif self.mode == "direct":
            R.finish(self.S, np.zeros((1, 1, 1)), True, *args, L1, y0, y1, 0, ray0)
        else:
            Sd = np.zeros((y1 - y0, nW))
            N = np.zeros((y1 - y0, nW), np.int32)
            R.raster_single(self._order(b0, b1), self.band_start, self.band_tris, bh, nH, nW,
                            *self._bands(), *args[1:5], Sd, N, y0)
            S = np.empty((y1 - y0, nW))
            R.reduce_chunks(Sd[None], N[None], self.FL, S)
            R.finish(S, np.zeros((1, 1, 1)), True, *args, L1, y0, y1, y0, ray0)
        if self.nb > 1:
            L[:, self.keep[0]] = L1[:, 0]
        return r0, r1, L


def _setup(R, F, XY, w, huge, V, perspective, r0, FL, nW, nH, sides, status, box, B, where,
           band_height, K, depth_ok):
    """Cull the triangles (their ``status`` and sample ``box``) and bin those that cover
    samples by bands of ``band_height`` detector rows: ``(band_start, band_tris)``. The
    rasters compute each triangle's plane where they raster it. ``K``, ``depth_ok``: see
    :func:`_raster_calls.cull_triangles`."""
    bands = R.cull_and_bin(F, XY, w, huge, perspective, FL, nW, nH, status, box, V, r0, sides,
                           band_height, K=K, depth_ok=depth_ok)
    if not depth_ok and status.min() <= ERR_STRADDLE:
        _refuse(*where, B, int(np.flatnonzero(status <= ERR_STRADDLE)[0]), r0, w, F)
    return bands
