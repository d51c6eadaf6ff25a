"""The fast engine: a watertight fixed-point footprint rasteriser (numba).

For a detector grid every ray shares the source (point source) or the direction (parallel
beam), so tracing all hits is rasterising the scene's triangles onto the detector:

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
5. **Path lengths**: one body: ``L = sum(exit depths) - sum(entry depths)`` (+ the detector depth
   when the ray is still inside there), accumulated per ray in one parallel pass over the
   triangles (one accumulator per thread; for very large detectors, per band of rows); no hit
   list. Several bodies: per
   band of detector rows, the hits of each ray are counted, stored, sorted and swept with the
   reference semantics of :func:`xray_viz.attenuation.path_lengths` (highest precedence among
   the bodies containing a point wins). Memory is O(triangles + rays + hits of one band).

The result is cached per (meshes, source, detector, supersampling): re-rendering the same
geometry with other energies or materials costs nothing, and the per-mesh set-up (faces sorted
along the Morton order of their vertices, vertices numbered in order of first use by those faces,
concatenated over bodies) is cached per mesh.

Limits: meshes must be closed and outward oriented (as for the NumPy engine); a body crossing
the plane of the source is refused with a :class:`~xray_viz.errors.SceneError` (the NumPy engine
traces it). Snapping moves projected vertices by at most ``2**-23`` of a grid step: the
watertightness is exact, and the path length of a ray grazing a silhouette within that distance
differs from the exact one by the chord there (below 1e-9 of the body size in the stress suite).
Float64 throughout; there is no float32 path.

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

__all__ = ["fast_path_lengths", "trace_once", "clear_caches", "FRAC_BITS"]

_MESH_CACHE: "OrderedDict[tuple, tuple]" = OrderedDict()
_L_CACHE: "OrderedDict[tuple, np.ndarray]" = OrderedDict()
_MESH_CACHE_SIZE = 8
_L_CACHE_SIZE = 4


def clear_caches() -> None:
    """Forget cached meshes and path lengths (for timing cold runs)."""
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


def _geometry(scene):
    """Concatenated vertices (V, 3) float64, faces (T, 3) int64 and triangle bodies (T,) int32,
    cached per tuple of meshes."""
    key = tuple(_mesh_key(b) for b in scene.bodies)
    hit = _MESH_CACHE.get(key)
    if hit is not None:
        _MESH_CACHE.move_to_end(key)
        return key, hit
    verts, faces, owner = [], [], []
    offset = 0
    for k, body in enumerate(scene.bodies):
        v, f = _spatial_order(np.asarray(body.vertices, dtype=np.float64),
                              np.asarray(body.faces, dtype=np.int64))
        verts.append(v)
        faces.append(f + offset)
        owner.append(np.full(len(f), k, np.int32))
        offset += len(v)
    V = np.ascontiguousarray(np.concatenate(verts)) if verts else np.zeros((0, 3))
    F = np.ascontiguousarray(np.concatenate(faces), dtype=np.int32 if offset < 2**31 else np.int64) \
        if faces else np.zeros((0, 3), np.int32)
    B = np.concatenate(owner) if owner else np.zeros(0, np.int32)
    for a in (V, F, B):
        a.setflags(write=False)
    _MESH_CACHE[key] = (V, F, B)
    while len(_MESH_CACHE) > _MESH_CACHE_SIZE:
        _MESH_CACHE.popitem(last=False)
    return key, (V, F, B)


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


def _refuse(scene, B, t, r0, w, F):
    body = scene.bodies[int(B[t])].name
    ws = w[F[t]]
    perspective = scene.source.kind != "parallel"
    if ws.min() < 0 or (perspective and ws.min() <= 0):
        raise SceneError(
            f"body {body!r} crosses the plane of the source (through {r0.tolist()}, across the "
            "beam): the fast engine cannot project it; move the source back or use "
            "engine='numpy'")
    raise SceneError(
        f"body {body!r} is too close to the plane of the source to project onto the detector; "
        "move the source back or use engine='numpy'")


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
    >>> L.shape, round(float(L.max()), 3)
    ((65536, 1), 79.998)
    """
    n = int(supersample)
    if n < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    W, H = scene.detector.shape
    if keep_hits or (n > 1 and (W == 1 or H == 1)):
        from xray_viz.render import _numpy_path_lengths

        return _numpy_path_lengths(scene, supersample=n, keep_hits=keep_hits)
    gkey, (V, F, B) = _geometry(scene)
    src, det = scene.source, scene.detector
    key = (gkey, tuple(src.position.tolist()), src.kind, tuple(det.center.tolist()),
           tuple(det.up.tolist()), tuple(det.shape), tuple(det.pitch), n,
           tuple(scene.precedence.tolist()) if len(scene.bodies) > 1 else ())
    if cache:
        hit = _L_CACHE.get(key)
        if hit is not None:
            _L_CACHE.move_to_end(key)
            return hit, None
    L = trace_once(scene, supersample=n, _geometry_arrays=(V, F, B))
    if cache:
        L.setflags(write=False)
        _L_CACHE[key] = L
        while len(_L_CACHE) > _L_CACHE_SIZE:
            _L_CACHE.popitem(last=False)
    return L, None


def trace_once(scene, *, supersample: int = 1, _geometry_arrays=None) -> np.ndarray:
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
        return _trace(scene, supersample=supersample, geometry_arrays=_geometry_arrays)


def _trace(scene, *, supersample, geometry_arrays):
    from xray_viz.tracing import _raster as R

    n = int(supersample)
    W, H = scene.detector.shape
    nb = len(scene.bodies)
    V, F, B = _geometry(scene)[1] if geometry_arrays is None else geometry_arrays
    n_rays = W * H * n * n
    if nb == 0 or len(F) == 0:
        return np.zeros((n_rays, nb))
    perspective = scene.source.kind != "parallel"
    r0, center, f, eu, ev, FL, sx, sy, bx, by, Ex, Ey, P00 = _frame(scene, n)
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
    if nb == 1 and n_chunks * nH * nW <= _DIRECT_MAX_SAMPLES:
        # One body: a single pass over the triangles, one accumulator per thread.
        Sc, Nc = _accumulators(n_chunks, nH, nW)
        err = np.empty(n_chunks, np.int64)
        depth_ok = bool(w.min() > 0 and w.max() < FL and not huge.any())
        R.raster_direct(n_chunks, F, XY, w, huge, V, perspective, r0, P0, Ex, Ey, f, FL, nW, nH,
                        depth_ok, Sc, Nc, err, K)
        if err.max() >= 0:
            _refuse(scene, B, int(err.max()), r0, w, F)
        S = np.empty((nH, nW))
        R.reduce_chunks(Sc, Nc, FL, S)
        L = np.zeros((n_rays, 1))
        R.finish(S, np.zeros((1, 1, 1)), True, FL, perspective, P0, Ex, Ey, n, W, H, L)
        return L
    R.cull_triangles(F, XY, w, huge, perspective, FL, nW, nH, status, box)
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
    L = np.zeros((n_rays, nb))
    if nb == 1:
        Sd = np.zeros((nH, nW))
        N = np.zeros((nH, nW), np.int32)
        R.raster_single(order, band_start, band_tris, band_height, nH, nW, tri, F, XY, kind,
                        cbox, orient, coef, wrange, B, FL, Sd, N)
        S = np.empty((nH, nW))
        R.reduce_chunks(Sd[None], N[None], FL, S)
        Lf = np.zeros((1, 1, 1))
        R.finish(S, Lf, True, FL, perspective, P0, Ex, Ey, n, W, H, L)
    else:
        prec = np.ascontiguousarray(scene.precedence, dtype=np.int64)
        R.raster_multi(order, band_start, band_tris, band_height, nH, nW, tri, F, XY, kind,
                       cbox, orient, coef, wrange, B, FL, prec, perspective, P0, Ex, Ey, n, W,
                       H, L)
    return L
