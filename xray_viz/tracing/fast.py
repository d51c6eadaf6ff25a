"""The fast engine: a watertight fixed-point footprint rasteriser (numba).

For a detector grid every ray shares the source (point source) or the direction (parallel
beam), so tracing all hits is rasterising the scene's triangles onto the detector:

0. **Cull bodies**: a body whose bounding box (cached per mesh) lies wholly outside the beam -
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
   :func:`xray_viz.meshes.repair.simple_winding`, cached per mesh):
   ``L = sum(exit depths) - sum(entry depths)`` (+ the detector depth when the ray is still
   inside there), accumulated per ray in one parallel pass over the triangles (one accumulator
   per thread; for very large detectors, per band of rows); no hit list. Otherwise (several
   bodies, or one body of overlapping, nested or hollow pieces): per band of detector rows,
   the hits of each ray are counted, stored, sorted and swept with the reference semantics of
   :func:`xray_viz.attenuation.path_lengths`: a body contains the stretches of ray where the
   winding number of its surface is positive (the nonzero rule: overlapping pieces give
   their union, an inward piece inside an outward one a cavity), and the highest precedence
   among the bodies containing a stretch wins. Memory is O(triangles + rays + hits of one
   band).

The result is cached per (meshes, source, detector, supersampling): re-rendering the same
geometry with other energies or materials costs nothing, and the per-mesh set-up (faces sorted
along the Morton order of their vertices, vertices numbered in order of first use by those faces,
concatenated over the bodies in the beam) is cached per mesh.

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
float32-against-float64 error to report; the stress suite (``tests/test_stress.py``) measures
the float64 engines against exact rational references instead.

Rays are the ideal grid of :func:`xray_viz.geometry.detector_rays`; the engine agrees with the
NumPy reference engine to rounding (~1e-12 relative) except on rays lying *in* a face plane,
whose length is ambiguous (either one-sided limit is correct).
"""

from __future__ import annotations

import math
import os
import threading
from collections import OrderedDict

import numba
import numpy as np

from xray_viz.errors import SceneError
from xray_viz.geometry import detector_axes
from xray_viz.tracing._raster import FRAC_BITS

__all__ = ["fast_path_lengths", "trace_once", "clear_caches", "visible_bodies", "FRAC_BITS"]

_PREP_CACHE: "OrderedDict[tuple, tuple]" = OrderedDict()
_MESH_CACHE: "OrderedDict[tuple, tuple]" = OrderedDict()
_L_CACHE: "OrderedDict[tuple, np.ndarray]" = OrderedDict()
_PREP_CACHE_SIZE = 64
_PREP_CACHE_BYTES = 512 << 20
_MESH_CACHE_SIZE = 8
_L_CACHE_SIZE = 4


def clear_caches() -> None:
    """Forget cached meshes and path lengths (for timing cold runs)."""
    _PREP_CACHE.clear()
    _MESH_CACHE.clear()
    _L_CACHE.clear()
    _WORK.clear()


def _mesh_key(body):
    mesh = body.mesh
    try:
        h = hash(mesh)
    except TypeError:
        h = None
    return (id(mesh), h)


def _spatial_order(v, f):
    """Faces sorted along the Morton (Z-curve) order of their first vertex, and vertices
    numbered in order of first use by those faces, so that the per-call passes over triangles
    and vertices touch memory nearly in sequence. Projection independent: done once per mesh."""
    if len(v) < 4096:
        return np.ascontiguousarray(v), f
    lo, hi = v.min(0), v.max(0)
    q = ((v - lo) / np.maximum(hi - lo, 1e-300) * 1023).astype(np.uint64)
    code = np.zeros(len(v), np.uint64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    order = np.argsort(code, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    f = rank[f]
    f = f[np.argsort(f.min(axis=1), kind="stable")]
    v = v[order]
    # Renumber the vertices in order of first use by the sorted faces: the per-call gathers
    # through the faces then walk the vertex arrays nearly in sequence (1.3M faces: -25 % time).
    from xray_viz.tracing._raster import first_use_rank

    rank = first_use_rank(np.ascontiguousarray(f).ravel(), len(v))
    order = np.empty_like(rank)
    order[rank] = np.arange(len(rank))
    return np.ascontiguousarray(v[order]), np.ascontiguousarray(rank[f])


def _prepared(body):
    """One mesh's vertices (V, 3) float64 and faces (T, 3) int32/int64 in spatial order
    (:func:`_spatial_order`), cached per mesh."""
    key = _mesh_key(body)
    hit = _PREP_CACHE.get(key)
    if hit is not None:
        _PREP_CACHE.move_to_end(key)
        return hit
    v, f = _spatial_order(np.asarray(body.vertices, dtype=np.float64),
                          np.asarray(body.faces, dtype=np.int64))
    f = np.array(f, dtype=np.int32 if len(v) < 2**31 else np.int64, order="C")
    if np.may_share_memory(v, body.mesh.vertices):
        v = v.copy()                    # small meshes: not a view of the mesh's own data
    for a in (v, f):
        a.setflags(write=False)
    _PREP_CACHE[key] = (v, f)
    # Bounded in entries and in bytes (a viewer turning a big mesh makes a new one per frame).
    while len(_PREP_CACHE) > 1 and (
            len(_PREP_CACHE) > _PREP_CACHE_SIZE or
            sum(a.nbytes + b.nbytes for a, b in _PREP_CACHE.values()) > _PREP_CACHE_BYTES):
        _PREP_CACHE.popitem(last=False)
    return v, f


def _geometry(scene, keep=None):
    """Concatenated vertices (V, 3) float64, faces (T, 3) int32 (int64 beyond 2**31 vertices)
    and triangle bodies (T,) int32 (indices into ``scene.bodies``) of the bodies ``keep``
    (default: all), cached per tuple of (body index, mesh)."""
    keep = tuple(range(len(scene.bodies))) if keep is None else tuple(keep)
    key = tuple((k, _mesh_key(scene.bodies[k])) for k in keep)
    hit = _MESH_CACHE.get(key)
    if hit is not None:
        _MESH_CACHE.move_to_end(key)
        return key, hit
    parts = [_prepared(scene.bodies[k]) for k in keep]
    if len(parts) == 1:
        V, F = parts[0]                 # shared with the per-mesh cache: no copy
    elif parts:
        offset = np.cumsum([0] + [len(v) for v, _ in parts])
        wide = offset[-1] >= 2**31
        V = np.ascontiguousarray(np.concatenate([v for v, _ in parts]))
        F = np.ascontiguousarray(np.concatenate(
            [f.astype(np.int64) + o for (_, f), o in zip(parts, offset)]),
            dtype=np.int64 if wide else np.int32)
    else:
        V, F = np.zeros((0, 3)), np.zeros((0, 3), np.int32)
    B = np.concatenate([np.full(len(f), k, np.int32) for k, (_, f) in zip(keep, parts)]) \
        if parts else np.zeros(0, np.int32)
    for a in (V, F, B):
        a.setflags(write=False)
    _MESH_CACHE[key] = (V, F, B)
    while len(_MESH_CACHE) > _MESH_CACHE_SIZE:
        _MESH_CACHE.popitem(last=False)
    return key, (V, F, B)


def _beam(scene, frame):
    """The beam's bounding planes (:func:`xray_viz.attenuation.beam_planes`), for any
    supersampling, widened by a pixel (:func:`xray_viz.attenuation.beam_half_widths`)."""
    from xray_viz.attenuation import beam_half_widths, beam_planes

    r0, center, f, eu, ev, FL = frame[:6]
    hu, hv = beam_half_widths(scene.detector)
    return beam_planes(r0, f, eu, ev, FL, hu, hv, scene.source.kind != "parallel")


def visible_bodies(scene, planes=None) -> tuple:
    """Indices of the bodies whose bounding box meets the beam (any supersampling); the others
    are culled as a whole: no vertex of theirs is projected, their path lengths are zero.

    Boxes are cached per mesh (:func:`xray_viz.attenuation.mesh_bounds`). A body is culled when
    its box lies wholly outside one side plane of the beam (the pyramid from a point source
    through the detector's edges, the slab box of a parallel beam), wholly behind the plane of
    the source or wholly beyond the detector.
    """
    from xray_viz.attenuation import boxes_outside_beam, mesh_bounds

    if not scene.bodies:
        return ()
    if planes is None:
        planes = _beam(scene, _frame(scene, 1))
    boxes = [mesh_bounds(b.mesh) for b in scene.bodies]
    out = boxes_outside_beam(np.array([b[0] for b in boxes]), np.array([b[1] for b in boxes]),
                             np.asarray(scene.source.position, np.float64), planes)
    return tuple(int(k) for k in np.flatnonzero(~out))


def _frame(scene, n):
    """Detector frame and fine-grid mapping (see :mod:`xray_viz.tracing._raster`)."""
    r0 = np.asarray(scene.source.position, np.float64)
    center = np.asarray(scene.detector.center, np.float64)
    f, eu, ev = detector_axes(r0, center, scene.detector.up)
    FL = float(np.linalg.norm(r0 - center))
    W, H = scene.detector.shape
    px, py = scene.detector.pitch
    # Fine coordinate of a detector offset (a, b) mm from the centre.
    sx, sy = n / px, n / py
    bx = n * (W - 1) / 2 + (n - 1) / 2
    by = n * (H - 1) / 2 + (n - 1) / 2
    Ex = (px / n) * eu
    Ey = (py / n) * ev
    P00 = -bx * Ex - by * Ey          # offset of fine sample (0, 0) from the detector centre
    return r0, center, f, eu, ev, FL, sx, sy, bx, by, Ex, Ey, P00


_WORK: dict = {}
_LOCK = threading.RLock()     # the scratch arrays are shared: one trace at a time


def _workspace(n_vertices, n_triangles):
    """Scratch arrays reused between calls (fresh pages cost more than the projection)."""
    if _WORK.get("size") != (n_vertices, n_triangles):
        _WORK["size"] = (n_vertices, n_triangles)
        _WORK["arrays"] = (np.empty((n_vertices, 2), np.int64), np.empty(n_vertices),
                           np.empty(n_vertices, np.bool_), np.empty(n_triangles, np.int8),
                           np.empty((n_triangles, 4), np.int64), np.empty(n_vertices, np.int32))
    return _WORK["arrays"]


#: Above this many (threads x samples), one body is traced by bands (memory) not per thread.
_DIRECT_MAX_SAMPLES = 1 << 23


#: How to fall back to the reference engine, for the refusal messages.
_USE_NUMPY = "use the NumPy engine (engine='numpy' in Python, --engine numpy on the command line)"


def _refuse(scene, B, t, r0, w, F):
    body = scene.bodies[int(B[t])].name
    ws = w[F[t]]
    perspective = scene.source.kind != "parallel"
    if ws.min() < 0 or (perspective and ws.min() <= 0):
        raise SceneError(
            f"body {body!r} crosses the plane of the source (through {r0.tolist()}, across the "
            f"beam) within the beam's cone: the fast engine cannot project it; move the source "
            f"back or {_USE_NUMPY}")
    raise SceneError(
        f"body {body!r} is too close to the plane of the source to project onto the detector; "
        f"move the source back or {_USE_NUMPY}")


def _accumulators(n_chunks, nH, nW):
    """Zeroed per-thread accumulators, reused between calls (no fresh pages to fault in)."""
    key = (n_chunks, nH, nW)
    if _WORK.get("acc_key") != key:
        _WORK["acc_key"] = key
        _WORK["acc"] = (np.zeros((n_chunks, nH, nW)), np.zeros((n_chunks, nH, nW), np.int32))
    else:
        for a in _WORK["acc"]:
            a.fill(0)
    return _WORK["acc"]


def _band_order(n_bands):
    # Interleave the bands so a static split over threads balances the work.
    return np.concatenate([np.arange(0, n_bands, 2), np.arange(1, n_bands, 2)]).astype(np.int64)


def fast_path_lengths(scene, *, supersample: int = 1, keep_hits: bool = False, cache: bool = True):
    """Effective path lengths of the detector rays through every body (engine ``"fast"``).

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
        Reuse the result of an earlier call on the same meshes, source, detector and
        supersampling (the default). The returned array is then shared and read-only.

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
    n = int(supersample)
    if n < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    W, H = scene.detector.shape
    if keep_hits or (n > 1 and (W == 1 or H == 1)):
        from xray_viz.render import _numpy_path_lengths

        return _numpy_path_lengths(scene, supersample=n, keep_hits=keep_hits)
    gkey = tuple(_mesh_key(b) for b in scene.bodies)
    src, det = scene.source, scene.detector
    key = (gkey, tuple(src.position.tolist()), src.kind, tuple(det.center.tolist()),
           tuple(det.up.tolist()), tuple(det.shape), tuple(det.pitch), n,
           tuple(scene.precedence.tolist()) if len(scene.bodies) > 1 else ())
    if cache:
        hit = _L_CACHE.get(key)
        if hit is not None:
            _L_CACHE.move_to_end(key)
            return hit, None
    L = trace_once(scene, supersample=n)
    if cache:
        L.setflags(write=False)
        _L_CACHE[key] = L
        while len(_L_CACHE) > _L_CACHE_SIZE:
            _L_CACHE.popitem(last=False)
    return L, None


def trace_once(scene, *, supersample: int = 1) -> np.ndarray:
    """Trace a scene's detector rays with the fast engine, without the result cache.

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
    with _LOCK:
        return _trace(scene, supersample=supersample)


def _trace(scene, *, supersample):
    from xray_viz.meshes.repair import simple_winding
    from xray_viz.tracing import _raster as R

    n = int(supersample)
    W, H = scene.detector.shape
    nb = len(scene.bodies)
    n_rays = W * H * n * n
    if nb == 0:
        return np.zeros((n_rays, 0))
    frame = _frame(scene, n)
    r0, center, f, eu, ev, FL, sx, sy, bx, by, Ex, Ey, P00 = frame
    planes = _beam(scene, frame)
    keep = visible_bodies(scene, planes)
    if not keep:
        return np.zeros((n_rays, nb))
    V, F, B = _geometry(scene, keep)[1]
    if len(F) == 0:
        return np.zeros((n_rays, nb))
    sides = np.ascontiguousarray(planes[:4])
    perspective = scene.source.kind != "parallel"
    nW, nH = W * n, H * n
    XY, w, huge, status, box, K = _workspace(len(V), len(F))
    if perspective:
        R.project_vertices(V, r0, f, eu, ev, sx * FL, bx, sy * FL, by, True, XY, w, huge,
                           nW, nH, K)
        P0 = (center + P00) - r0
    else:
        R.project_vertices(V, r0, f, eu, ev, sx, bx, sy, by, False, XY, w, huge, nW, nH, K)
        P0 = P00
    n_chunks = numba.get_num_threads()
    # The signed depth sum is a body's path length only where its winding number is 0 or 1
    # (cached per mesh by the mesh check every Scene runs: a dictionary look-up here).
    if len(keep) == 1 and simple_winding(scene.bodies[keep[0]].mesh):
        L1 = _trace_single(R, n_chunks, F, XY, w, huge, V, perspective, r0, P0, Ex, Ey, f, FL,
                           nW, nH, K, sides, status, box, B, n, W, H, scene)
        if nb == 1:
            return L1
        L = np.zeros((n_rays, nb))
        L[:, keep[0]] = L1[:, 0]
        return L
    tri, kind, orient, cbox, coef, wrange, order, band_start, band_tris, band_height = \
        _setup(R, F, XY, w, huge, V, perspective, r0, P0, Ex, Ey, f, FL, nW, nH, sides,
               status, box, B, scene)
    L = np.zeros((n_rays, nb))
    prec = np.ascontiguousarray(scene.precedence, dtype=np.int64)
    R.raster_multi(order, band_start, band_tris, band_height, nH, nW, tri, F, XY, kind,
                   cbox, orient, coef, wrange, B, FL, prec, perspective, P0, Ex, Ey, n, W,
                   H, L)
    return L


def _trace_single(R, n_chunks, F, XY, w, huge, V, perspective, r0, P0, Ex, Ey, f, FL, nW, nH,
                  K, sides, status, box, B, n, W, H, scene):
    """Path lengths (n_rays, 1) of the one body left in the beam, by signed depth sums
    (exact only when its winding number is 0 or 1: see
    :func:`xray_viz.meshes.repair.simple_winding`)."""
    L = np.zeros((W * H * n * n, 1))
    if n_chunks * nH * nW <= _DIRECT_MAX_SAMPLES:
        # A single pass over the triangles, one accumulator per thread.
        Sc, Nc = _accumulators(n_chunks, nH, nW)
        err = np.empty(n_chunks, np.int64)
        depth_ok = bool(w.min() > 0 and w.max() < FL and not huge.any())
        R.raster_direct(n_chunks, F, XY, w, huge, V, perspective, r0, P0, Ex, Ey, f, FL, nW, nH,
                        depth_ok, Sc, Nc, err, K, sides)
        if err.max() >= 0:
            _refuse(scene, B, int(err.max()), r0, w, F)
        S = np.empty((nH, nW))
        R.reduce_chunks(Sc, Nc, FL, S)
    else:
        tri, kind, orient, cbox, coef, wrange, order, band_start, band_tris, band_height = \
            _setup(R, F, XY, w, huge, V, perspective, r0, P0, Ex, Ey, f, FL, nW, nH, sides,
                   status, box, B, scene)
        Sd = np.zeros((nH, nW))
        N = np.zeros((nH, nW), np.int32)
        R.raster_single(order, band_start, band_tris, band_height, nH, nW, tri, F, XY, kind,
                        cbox, orient, coef, wrange, B, FL, Sd, N)
        S = np.empty((nH, nW))
        R.reduce_chunks(Sd[None], N[None], FL, S)
    R.finish(S, np.zeros((1, 1, 1)), True, FL, perspective, P0, Ex, Ey, n, W, H, L)
    return L


def _setup(R, F, XY, w, huge, V, perspective, r0, P0, Ex, Ey, f, FL, nW, nH, sides, status,
           box, B, scene):
    """Cull, set up and bin the triangles by bands of detector rows (banded rasters)."""
    R.cull_triangles(F, XY, w, huge, perspective, FL, nW, nH, status, box, V, r0, sides)
    if status.min() <= R.ERR_STRADDLE:
        _refuse(scene, B, int(np.flatnonzero(status <= R.ERR_STRADDLE)[0]), r0, w, F)
    tri = np.flatnonzero(status).astype(np.int64)
    M = len(tri)
    kind = np.empty(M, np.int8)
    orient = np.empty(M, np.int8)
    cbox = np.empty((M, 4), np.int64)
    coef = np.empty((M, 6))
    wrange = np.empty((M, 2))
    R.setup_planes(tri, V, F, w, status, box, perspective, r0, P0, Ex, Ey, f, FL,
                   kind, orient, cbox, coef, wrange)
    n_bands = int(min(nH, max(2, 16 * (os.cpu_count() or 2))))
    band_height = int(math.ceil(nH / n_bands))
    n_bands = int(math.ceil(nH / band_height))
    band_start, band_tris = R.bin_triangles(cbox, band_height, n_bands)
    order = _band_order(n_bands)
    return tri, kind, orient, cbox, coef, wrange, order, band_start, band_tris, band_height
