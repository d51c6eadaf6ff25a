"""Compiled mesh checks (numba): pymeshlab's self-intersection test, same answers, faster.

:func:`self_intersections` flags the faces that pymeshlab's
``compute_selection_by_self_intersections_per_face`` selects (vcglib's
``tri::Clean::SelfIntersections``), by the same arithmetic in the same order, so that the two
give the same set of faces bit for bit:

* candidate pairs are the faces whose bounding boxes *strictly* overlap on every axis
  (``Box3::Collide``; vcglib finds them with a uniform grid, here a uniform grid hashed into
  buckets, each pair tested once, in the cell holding the larger corner of the two boxes);
* a pair is tested with the lower-numbered face first (vcglib's loop order) by
  ``Clean::TestFaceFaceIntersection``: faces with the same three vertices intersect; faces
  sharing an edge (two vertices) do not; faces sharing one vertex intersect when the edge
  opposite that vertex, moved half way towards it, crosses the other face strictly inside
  (``IntersectionSegmentTriangle``: a box test, a line-box test, then Moller-Trumbore with
  ``EPSIL = 1e-6``); faces sharing nothing are tested by Moller's 1997 ``NoDivTriTriIsect``
  (first plane normalised, no epsilon; coplanar faces by their edges and corners projected
  on the plane of the largest normal component).

Floating-point double precision, as pymeshlab's meshes (its ``Scalarm`` is ``double``); the
expressions keep vcglib's order of operations (no fused multiply-add, no reassociation), so
each comparison sees the same numbers. ``tests/test_self_intersection_kernel.py`` checks the
sets against pymeshlab on the phantoms and on random overlapping meshes.

:func:`edge_facts` gives the edge facts of ``repair._edge_facts`` (boundary edges, watertight,
winding, edge-connected pieces) in one pass over the edges grouped by their lower vertex.

Each kernel has one specialisation (:data:`SIGNATURES`), compiled on first use (or loaded from
numba's cache, :mod:`xray_viz.tracing._numba_cache`); :func:`is_ready` says whether that costs
nothing, :func:`compile_kernels` compiles them, :func:`prepare` in a background process filling the
cache.
"""

from __future__ import annotations

import math
import typing

import numpy as np
from numba import njit
from numba.core import types as _nt

# Imported before the kernels are defined: it gives them their disk cache.
from xray_viz.tracing import _numba_cache  # noqa: F401
from xray_viz.tracing._compile import KernelSet

_EPSIL = 0.000001
#: Fewest faces per thread of the self-intersection sweep (below, one thread).
_PARALLEL_FACES = 20_000


@njit(cache=True, nogil=True, error_model="numpy")
def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@njit(cache=True, nogil=True, error_model="numpy")
def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit(cache=True, nogil=True, error_model="numpy")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, nogil=True, error_model="numpy")
def _normalized(a):
    """``Point3::Normalize``."""
    n = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    if n > 0.0:
        return (a[0] / n, a[1] / n, a[2] / n)
    return a


@njit(cache=True, nogil=True, error_model="numpy")
def _point_in_tri(v, u0, u1, u2, i0, i1):
    """vcglib's ``POINT_IN_TRI``: ``v`` strictly inside the projected triangle ``u``."""
    a = u1[i1] - u0[i1]
    b = -(u1[i0] - u0[i0])
    c = -a * u0[i0] - b * u0[i1]
    d0 = a * v[i0] + b * v[i1] + c
    a = u2[i1] - u1[i1]
    b = -(u2[i0] - u1[i0])
    c = -a * u1[i0] - b * u1[i1]
    d1 = a * v[i0] + b * v[i1] + c
    a = u0[i1] - u2[i1]
    b = -(u0[i0] - u2[i0])
    c = -a * u2[i0] - b * u2[i1]
    d2 = a * v[i0] + b * v[i1] + c
    return d0 * d1 > 0.0 and d0 * d2 > 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def _edge_edge(ax, ay, v0, u0, u1, i0, i1):
    """vcglib's ``EDGE_EDGE_TEST`` of edge ``v0 + (ax, ay)`` against edge ``u0 u1``."""
    bx = u0[i0] - u1[i0]
    by = u0[i1] - u1[i1]
    cx = v0[i0] - u0[i0]
    cy = v0[i1] - u0[i1]
    f = ay * bx - ax * by
    d = by * cx - bx * cy
    if (f > 0 and d >= 0 and d <= f) or (f < 0 and d <= 0 and d >= f):
        e = ax * cy - ay * cx
        if f > 0:
            if e >= 0 and e <= f:
                return True
        else:
            if e <= 0 and e >= f:
                return True
    return False


@njit(cache=True, nogil=True, error_model="numpy")
def _edge_against_tri(v0, v1, u0, u1, u2, i0, i1):
    ax = v1[i0] - v0[i0]
    ay = v1[i1] - v0[i1]
    return (_edge_edge(ax, ay, v0, u0, u1, i0, i1) or _edge_edge(ax, ay, v0, u1, u2, i0, i1)
            or _edge_edge(ax, ay, v0, u2, u0, i0, i1))


@njit(cache=True, nogil=True, error_model="numpy")
def _coplanar(n, v0, v1, v2, u0, u1, u2):
    """vcglib's ``coplanar_tri_tri``."""
    a0, a1, a2 = abs(n[0]), abs(n[1]), abs(n[2])
    if a0 > a1:
        if a0 > a2:
            i0, i1 = 1, 2
        else:
            i0, i1 = 0, 1
    else:
        if a2 > a1:
            i0, i1 = 0, 1
        else:
            i0, i1 = 0, 2
    if (_edge_against_tri(v0, v1, u0, u1, u2, i0, i1)
            or _edge_against_tri(v1, v2, u0, u1, u2, i0, i1)
            or _edge_against_tri(v2, v0, u0, u1, u2, i0, i1)):
        return True
    return _point_in_tri(v0, u0, u1, u2, i0, i1) or _point_in_tri(u0, v0, v1, v2, i0, i1)


@njit(cache=True, nogil=True, error_model="numpy")
def _interval(vv0, vv1, vv2, d0, d1, d2, d0d1, d0d2):
    """vcglib's ``NEWCOMPUTE_INTERVALS``: ``(ok, A, B, C, X0, X1)``, ``ok`` False when the
    triangles are coplanar."""
    if d0d1 > 0.0:
        return True, vv2, (vv0 - vv2) * d2, (vv1 - vv2) * d2, d2 - d0, d2 - d1
    if d0d2 > 0.0:
        return True, vv1, (vv0 - vv1) * d1, (vv2 - vv1) * d1, d1 - d0, d1 - d2
    if d1 * d2 > 0.0 or d0 != 0.0:
        return True, vv0, (vv1 - vv0) * d0, (vv2 - vv0) * d0, d0 - d1, d0 - d2
    if d1 != 0.0:
        return True, vv1, (vv0 - vv1) * d1, (vv2 - vv1) * d1, d1 - d0, d1 - d2
    if d2 != 0.0:
        return True, vv2, (vv0 - vv2) * d2, (vv1 - vv2) * d2, d2 - d0, d2 - d1
    return False, 0.0, 0.0, 0.0, 0.0, 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def _tri_tri(v0, v1, v2, u0, u1, u2):
    """vcglib's ``NoDivTriTriIsect`` (Moller 1997, first normal normalised, no epsilon)."""
    n1 = _normalized(_cross(_sub(v1, v0), _sub(v2, v0)))
    d1 = -_dot(n1, v0)
    du0 = _dot(n1, u0) + d1
    du1 = _dot(n1, u1) + d1
    du2 = _dot(n1, u2) + d1
    du0du1 = du0 * du1
    du0du2 = du0 * du2
    if du0du1 > 0.0 and du0du2 > 0.0:
        return False
    n2 = _cross(_sub(u1, u0), _sub(u2, u0))
    d2 = -_dot(n2, u0)
    dv0 = _dot(n2, v0) + d2
    dv1 = _dot(n2, v1) + d2
    dv2 = _dot(n2, v2) + d2
    dv0dv1 = dv0 * dv1
    dv0dv2 = dv0 * dv2
    if dv0dv1 > 0.0 and dv0dv2 > 0.0:
        return False
    d = _cross(n1, n2)
    big = abs(d[0])
    index = 0
    if abs(d[1]) > big:
        big = abs(d[1])
        index = 1
    if abs(d[2]) > big:
        index = 2
    ok, a, b, c, x0, x1 = _interval(v0[index], v1[index], v2[index], dv0, dv1, dv2, dv0dv1,
                                    dv0dv2)
    if not ok:
        return _coplanar(n1, v0, v1, v2, u0, u1, u2)
    ok, dd, e, f, y0, y1 = _interval(u0[index], u1[index], u2[index], du0, du1, du2, du0du1,
                                     du0du2)
    if not ok:
        return _coplanar(n1, v0, v1, v2, u0, u1, u2)
    xx = x0 * x1
    yy = y0 * y1
    xxyy = xx * yy
    tmp = a * xxyy
    s0 = tmp + b * x1 * yy
    s1 = tmp + c * x0 * yy
    tmp = dd * xxyy
    t0 = tmp + e * xx * y1
    t1 = tmp + f * xx * y0
    if s0 > s1:
        s0, s1 = s1, s0
    if t0 > t1:
        t0, t1 = t1, t0
    return not (s1 < t0 or t1 < s0)


@njit(cache=True, nogil=True, error_model="numpy")
def _collide(alo, ahi, blo, bhi):
    """``Box3::Collide``: strict overlap on every axis."""
    return (blo[0] < ahi[0] and bhi[0] > alo[0] and blo[1] < ahi[1] and bhi[1] > alo[1]
            and blo[2] < ahi[2] and bhi[2] > alo[2])


@njit(cache=True, nogil=True, error_model="numpy")
def _min3(a, b):
    return (min(a[0], b[0]), min(a[1], b[1]), min(a[2], b[2]))


@njit(cache=True, nogil=True, error_model="numpy")
def _max3(a, b):
    return (max(a[0], b[0]), max(a[1], b[1]), max(a[2], b[2]))


@njit(cache=True, nogil=True, error_model="numpy")
def _line_box_axis(o, d, lo, hi):
    """One axis of vcglib's ``IntersectionLineBox``: ``(middle, candidate plane, maxT)``."""
    if o < lo:
        return False, lo, (lo - o) / d if d != 0.0 else -1.0
    if o > hi:
        return False, hi, (hi - o) / d if d != 0.0 else -1.0
    return True, 0.0, -1.0


@njit(cache=True, nogil=True, error_model="numpy")
def _segment_box(blo, bhi, slo, shi, o, d):
    """vcglib's ``IntersectionSegmentBox`` after its box test: ``IntersectionLineBox`` of the
    line ``(o, d)`` and the box, then the point inside the segment's box."""
    m0, c0, t0 = _line_box_axis(o[0], d[0], blo[0], bhi[0])
    m1, c1, t1 = _line_box_axis(o[1], d[1], blo[1], bhi[1])
    m2, c2, t2 = _line_box_axis(o[2], d[2], blo[2], bhi[2])
    if m0 and m1 and m2:
        p = o
    else:
        w, tw = 0, t0
        if tw < t1:
            w, tw = 1, t1
        if tw < t2:
            w, tw = 2, t2
        if tw < 0.0:
            return False
        p0 = c0 if w == 0 else o[0] + tw * d[0]
        if w != 0 and (p0 < blo[0] or p0 > bhi[0]):
            return False
        p1 = c1 if w == 1 else o[1] + tw * d[1]
        if w != 1 and (p1 < blo[1] or p1 > bhi[1]):
            return False
        p2 = c2 if w == 2 else o[2] + tw * d[2]
        if w != 2 and (p2 < blo[2] or p2 > bhi[2]):
            return False
        p = (p0, p1, p2)
    return (slo[0] <= p[0] and p[0] <= shi[0] and slo[1] <= p[1] and p[1] <= shi[1]
            and slo[2] <= p[2] and p[2] <= shi[2])


@njit(cache=True, nogil=True, error_model="numpy")
def _segment_triangle(p0, p1, v0, v1, v2):
    """vcglib's ``IntersectionSegmentTriangle``: ``(hit, a, b)``."""
    slo = _min3(p0, p1)
    shi = _max3(p0, p1)
    tlo = _min3(_min3(v0, v1), v2)
    thi = _max3(_max3(v0, v1), v2)
    if not _collide(slo, shi, tlo, thi):
        return False, 0.0, 0.0
    d = _normalized(_sub(p1, p0))
    if not _segment_box(tlo, thi, slo, shi, p0, d):
        return False, 0.0, 0.0
    q = _sub(p0, p1)
    length = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2])
    # IntersectionLineTriangle (Moller-Trumbore) of the line (p0, d)
    e1 = _sub(v1, v0)
    e2 = _sub(v2, v0)
    pv = _cross(d, e2)
    det = _dot(e1, pv)
    tv = _sub(p0, v0)
    inv_det = 1.0 / det
    qv = _cross(tv, e1)
    if det > _EPSIL:
        u = _dot(tv, pv)
        if u < 0.0 or u > det:
            return False, 0.0, 0.0
        v = _dot(d, qv)
        if v < 0.0 or u + v > det:
            return False, 0.0, 0.0
    elif det < -_EPSIL:
        u = _dot(tv, pv)
        if u > 0.0 or u < det:
            return False, 0.0, 0.0
        v = _dot(d, qv)
        if v > 0.0 or u + v < det:
            return False, 0.0, 0.0
    else:
        return False, 0.0, 0.0
    t = _dot(e2, qv) * inv_det
    return t >= 0 and t <= length, u * inv_det, v * inv_det


@njit(cache=True, nogil=True, error_model="numpy")
def _point(vertices, i):
    return (vertices[i, 0], vertices[i, 1], vertices[i, 2])


@njit(cache=True, nogil=True, error_model="numpy")
def _half_way(p, sh):
    return (p[0] * 0.5 + sh[0], p[1] * 0.5 + sh[1], p[2] * 0.5 + sh[2])


@njit(cache=True, nogil=True, error_model="numpy")
def _face_face(vertices, faces, f0, f1):
    """vcglib's ``Clean::TestFaceFaceIntersection(f0, f1)``."""
    shared = 0
    i0 = i1 = -1
    for i in range(3):
        for j in range(3):
            if faces[f0, i] == faces[f1, j]:
                shared += 1
                if i0 < 0:
                    i0, i1 = i, j
    if shared == 3:
        return True
    if shared != 0 and shared != 1:
        return False
    a0 = _point(vertices, faces[f0, 0])
    a1 = _point(vertices, faces[f0, 1])
    a2 = _point(vertices, faces[f0, 2])
    b0 = _point(vertices, faces[f1, 0])
    b1 = _point(vertices, faces[f1, 1])
    b2 = _point(vertices, faces[f1, 2])
    if shared == 0:
        return _tri_tri(a0, a1, a2, b0, b1, b2)
    s = _point(vertices, faces[f0, i0])
    sh = (s[0] * 0.5, s[1] * 0.5, s[2] * 0.5)
    hit, a, b = _segment_triangle(
        _half_way(_point(vertices, faces[f0, (i0 + 1) % 3]), sh),
        _half_way(_point(vertices, faces[f0, (i0 + 2) % 3]), sh), b0, b1, b2)
    if hit:
        return not (a + b >= 1 or a <= _EPSIL or b <= _EPSIL)
    hit, a, b = _segment_triangle(
        _half_way(_point(vertices, faces[f1, (i1 + 1) % 3]), sh),
        _half_way(_point(vertices, faces[f1, (i1 + 2) % 3]), sh), a0, a1, a2)
    if hit:
        return not (a + b >= 1 or a <= _EPSIL or b <= _EPSIL)
    return False


@njit(cache=True, nogil=True, error_model="numpy")
def _cell(x, origin, inv, n):
    k = int(math.floor((x - origin) * inv))
    return min(max(k, 0), n - 1)


@njit(cache=True, nogil=True, error_model="numpy")
def _grid_boxes(vertices, faces, lo, hi, glo, dims):
    """The first half of :func:`_grid`: each face's bounding box (``lo``, ``hi``), the low
    corner of them all (``glo``) and the grid's cells per axis (``dims``); returns
    ``(inv, total)``: the inverse of the cell size and the number of (cell, face) entries.
    ``dims[0] == 0`` when no two boxes can overlap (fewer than two faces, or all in one point,
    or not finite)."""
    m = faces.shape[0]
    # (element by element: a slice assignment costs numba a second of compile)
    ghi = np.empty(3)
    for k in range(3):
        glo[k] = np.inf
        ghi[k] = -np.inf
    extent = 0.0
    for f in range(m):
        for k in range(3):
            a = vertices[faces[f, 0], k]
            b = vertices[faces[f, 1], k]
            c = vertices[faces[f, 2], k]
            lo[f, k] = min(min(a, b), c)
            hi[f, k] = max(max(a, b), c)
            glo[k] = min(glo[k], lo[f, k])
            ghi[k] = max(ghi[k], hi[f, k])
            extent += hi[f, k] - lo[f, k]
    span = 0.0
    for k in range(3):
        span = max(span, ghi[k] - glo[k])
    if m < 2 or not (span > 0.0) or not np.isfinite(span):
        # all in one point: no two boxes overlap strictly (or not finite)
        for k in range(3):
            dims[k] = 0
        return 0.0, 0
    # cells about four times the mean face extent (a face in ~2 cells: grid and sweep quicker
    # than at twice; benchmarks/notes/checks.md),
    # fewer than 2**20 along an axis, and made bigger while a face would be entered in too
    # many (one huge face among small ones)
    size = max(4.0 * extent / (3.0 * m), span / 2.0 ** 20)
    while True:
        inv = 1.0 / size
        total = 0
        for k in range(3):
            dims[k] = _cell(ghi[k], glo[k], inv, 2 ** 21) + 1
        for f in range(m):
            c = 1
            for k in range(3):
                c *= (_cell(hi[f, k], glo[k], inv, dims[k])
                      - _cell(lo[f, k], glo[k], inv, dims[k]) + 1)
            total += c
        if total <= 16 * m + 1024:
            return inv, total
        size *= 2.0


@njit(cache=True, nogil=True, error_model="numpy")
def _grid_place(faces, lo, hi, glo, inv, dims, start, face_id, pface, plo, phi, clo):
    """The faces renumbered in the order of the bucket of their low corner's cell (a counting
    sort, ``start`` zeros on entry, one more than the buckets: the faces of a cell near in
    memory), with their boxes (``plo``, ``phi``), low corner's cell (``clo``; the high
    corner's is recomputed where needed) and vertices (``pface``), ``face_id`` back to the
    mesh's numbers; written where they go, the faces read in order."""
    m = lo.shape[0]
    n_buckets = start.shape[0] - 1
    for f in range(m):
        key = ((_cell(lo[f, 0], glo[0], inv, dims[0]) * dims[1]
                + _cell(lo[f, 1], glo[1], inv, dims[1])) * dims[2]
               + _cell(lo[f, 2], glo[2], inv, dims[2]))
        start[key % n_buckets + 1] += 1
    for b in range(n_buckets):
        start[b + 1] += start[b]
    for f in range(m):
        c0 = _cell(lo[f, 0], glo[0], inv, dims[0])
        c1 = _cell(lo[f, 1], glo[1], inv, dims[1])
        c2 = _cell(lo[f, 2], glo[2], inv, dims[2])
        b = ((c0 * dims[1] + c1) * dims[2] + c2) % n_buckets
        j = start[b]
        start[b] += 1
        face_id[j] = f
        for k in range(3):
            plo[j, k] = lo[f, k]
            phi[j, k] = hi[f, k]
            pface[j, k] = faces[f, k]
        clo[j, 0] = c0
        clo[j, 1] = c1
        clo[j, 2] = c2


@njit(cache=True, nogil=True, error_model="numpy")
def _grid_entries(j_lo, j_hi, placing, phi, clo, glo, inv, dims, fill, keys, owner):
    """Every cell that the boxes of (renumbered) faces ``j_lo .. j_hi - 1`` meet: counted per
    bucket into ``fill`` (``placing`` False), or entered as (cell key, face) at ``fill[b]``,
    which counts on (``placing``). Ranges of faces counted apart, and entered from their
    offsets in each bucket (the ranges in order), give the entries of one pass, in order."""
    n_buckets = fill.shape[0]
    for f in range(j_lo, j_hi):
        c0 = _cell(phi[f, 0], glo[0], inv, dims[0])
        c1 = _cell(phi[f, 1], glo[1], inv, dims[1])
        c2 = _cell(phi[f, 2], glo[2], inv, dims[2])
        for x in range(clo[f, 0], c0 + 1):
            for y in range(clo[f, 1], c1 + 1):
                for z in range(clo[f, 2], c2 + 1):
                    key = (x * dims[1] + y) * dims[2] + z
                    b = key % n_buckets
                    if placing:
                        keys[fill[b]] = key
                        owner[fill[b]] = f
                    fill[b] += 1


def _grid(vertices, faces, *, finish=True):
    """The candidate pairs of :func:`_sweep_buckets`: every face's bounding box entered in the
    cells of a uniform grid it meets, the cells hashed into buckets; ``(start, keys, owner,
    plo, phi, clo, face_id, dims, widest, pface)``: CSR offsets of the buckets' ``keys`` and
    ``owner`` entries, then what :func:`_grid_place` gives, ``widest`` the most entries of a
    bucket; ``dims[0] == 0`` when no two boxes can overlap. With ``finish=False``, what
    :func:`_grid_finish` completes (the entries: on every thread of the sweep).

    The arrays are NumPy's, made here: NumPy asks the kernel for transparent huge pages for
    large arrays (where the system gives them on request: ``madvise`` on this project's
    machines), numba's own allocations do not; filling fresh pages was much of the grid's
    time (``benchmarks/notes/checks.md``).
    """
    m = len(faces)
    lo = np.empty((m, 3))
    hi = np.empty((m, 3))
    glo = np.empty(3)
    dims = np.zeros(3, np.int64)
    inv, total = KERNELS.kernel("_grid_boxes")(vertices, faces, lo, hi, glo, dims)
    if dims[0] == 0:
        z = np.zeros(1, np.int64)
        return z, z, z, lo, hi, np.zeros((0, 3), np.int64), z, dims, 0, np.zeros((0, 3),
                                                                              np.int64)
    # a cell's bucket: its key itself when the grid is small, else the key modulo an odd
    # number (neighbouring cells in neighbouring buckets)
    n_cells = int(dims[0]) * int(dims[1]) * int(dims[2])
    n_buckets = n_cells if n_cells <= total else (total // 4) | 1
    start = np.zeros(n_buckets + 1, np.int64)
    face_id = np.empty(m, np.int64)
    pface = np.empty((m, 3), np.int64)
    plo = np.empty((m, 3))
    phi = np.empty((m, 3))
    clo = np.empty((m, 3), np.int64)
    KERNELS.kernel("_grid_place")(faces, lo, hi, glo, inv, dims, start, face_id, pface, plo, phi, clo)
    del lo, hi
    placed = _Placed(plo, phi, clo, face_id, dims, pface, glo, float(inv), int(total),
                     n_buckets)
    return _grid_finish(placed) if finish else placed


def _grid_finish(placed):
    """The entries of a grid placed by ``_grid(..., finish=False)`` (a :class:`_Placed`;
    anything else is a finished grid, returned as it is): the faces in :func:`_sweep_threads`
    contiguous ranges, each range's cells counted per bucket on its own thread, then each
    range entered from its offsets in each bucket (after the entries of the ranges before it):
    the same arrays as one pass over the faces."""
    if not isinstance(placed, _Placed):
        return placed
    p = placed
    m, n_buckets = len(p.face_id), p.n_buckets
    kernel = KERNELS.kernel("_grid_entries")
    k = _pieces(m)
    cut = [m * j // k for j in range(k + 1)]
    counts = np.zeros((k, n_buckets), np.int64)
    none = np.zeros(0, np.int64)
    from xray_viz._threads import run_pieces

    run_pieces(lambda j: kernel(cut[j], cut[j + 1], False, p.phi, p.clo, p.glo, p.inv, p.dims,
                                counts[j], none, none), k)
    start = np.zeros(n_buckets + 1, np.int64)
    np.cumsum(counts.sum(axis=0), out=start[1:])
    fill = np.empty((k, n_buckets), np.int64)
    fill[0] = start[:-1]
    if k > 1:
        np.cumsum(counts[:-1], axis=0, out=fill[1:])
        fill[1:] += start[:-1]
    keys = np.empty(p.total, np.int64)
    owner = np.empty(p.total, np.int64)
    run_pieces(lambda j: kernel(cut[j], cut[j + 1], True, p.phi, p.clo, p.glo, p.inv, p.dims,
                                fill[j], keys, owner), k)
    widest = int(np.diff(start).max())
    return start, keys, owner, p.plo, p.phi, p.clo, p.face_id, p.dims, widest, p.pface


class _Placed(typing.NamedTuple):
    """A grid of :func:`_grid` before its entries (:func:`_grid_finish`)."""

    plo: np.ndarray
    phi: np.ndarray
    clo: np.ndarray
    face_id: np.ndarray
    dims: np.ndarray
    pface: np.ndarray
    glo: np.ndarray
    inv: float
    total: int
    n_buckets: int


@njit(cache=True, nogil=True, error_model="numpy")
def _sweep_buckets(b_lo, b_hi, vertices, faces, labels, flags, start, keys, owner, plo, phi, clo,
                   face_id, dims, widest, pface):
    """Set ``flags[f]`` for every face ``f`` of a pair that pymeshlab selects as
    self-intersecting among the entries of buckets ``b_lo .. b_hi - 1`` of
    :func:`_grid`; with ``labels`` (one per face, else empty), only pairs of
    faces of the same label count. Each pair is tested in one bucket only, and a flag is only
    ever set, so bucket ranges can be swept by concurrent threads: the flags do not depend on
    the split (a pair whose two faces are flagged already is not tested again, which changes
    no flag)."""
    # each bucket's entries sorted by (cell, low x): an insertion sort of (key, low x, face),
    # then the boxes gathered in that order, one array per bound (SoA), and swept along x
    skey = np.empty(widest, np.int64)
    sface = np.empty(widest, np.int64)
    x0 = np.empty(widest)
    x1 = np.empty(widest)
    y0 = np.empty(widest)
    y1 = np.empty(widest)
    z0 = np.empty(widest)
    z1 = np.empty(widest)
    hit = np.empty(widest, np.int64)
    d1 = dims[1]
    d2 = dims[2]
    for b in range(b_lo, b_hi):
        s0 = start[b]
        k = start[b + 1] - s0
        if k < 2:
            continue
        for p in range(k):
            f = owner[s0 + p]
            key = keys[s0 + p]
            x = plo[f, 0]
            j = p
            while j > 0 and (skey[j - 1] > key or (skey[j - 1] == key and x0[j - 1] > x)):
                skey[j] = skey[j - 1]
                x0[j] = x0[j - 1]
                sface[j] = sface[j - 1]
                j -= 1
            skey[j] = key
            x0[j] = x
            sface[j] = f
        for p in range(k):
            f = sface[p]
            x1[p] = phi[f, 0]
            y0[p] = plo[f, 1]
            y1[p] = phi[f, 1]
            z0[p] = plo[f, 2]
            z1[p] = phi[f, 2]
        for p in range(k - 1):
            key = skey[p]
            lx, hx, ly, hy, lz, hz = x0[p], x1[p], y0[p], y1[p], z0[p], z1[p]
            # the later entries of this cell whose box meets p's (Box3::Collide, strict):
            # sorted, so the first one starting beyond p's box ends the scan; the test itself
            # is branch free (a candidate is written, and kept when it passes)
            m = 0
            for q in range(p + 1, k):
                if skey[q] != key or not (x0[q] < hx):
                    break
                hit[m] = q
                m += (x1[q] > lx) & (y0[q] < hy) & (y1[q] > ly) & (z0[q] < hz) & (z1[q] > lz)
            if m == 0:
                continue
            fp = sface[p]
            for r in range(m):
                fq = sface[hit[r]]
                # test the pair once: in the cell holding the larger of the two low corners
                # (compared by key, one cell's one number: no divisions to decode this one)
                if ((max(clo[fp, 0], clo[fq, 0]) * d1 + max(clo[fp, 1], clo[fq, 1])) * d2
                        + max(clo[fp, 2], clo[fq, 2]) != key):
                    continue
                # faces sharing exactly two vertex uses (an edge) do not intersect
                # (TestFaceFaceIntersection's first answer): known before any coordinate,
                # from the faces' vertices in the grid's order (near in memory)
                shared = 0
                for a in range(3):
                    for c in range(3):
                        shared += pface[fp, a] == pface[fq, c]
                if shared != 0 and shared != 1 and shared != 3:
                    continue
                # the mesh's lower-numbered face first (vcglib's order)
                ga, gb = (fp, fq) if face_id[fp] < face_id[fq] else (fq, fp)
                f0 = face_id[ga]
                f1 = face_id[gb]
                if flags[f0] and flags[f1]:
                    continue
                if labels.shape[0] != 0 and labels[f0] != labels[f1]:
                    continue
                if _face_face(vertices, pface, ga, gb):
                    flags[f0] = True
                    flags[f1] = True


@njit(cache=True, nogil=True, error_model="numpy")
def _find(parent, a):
    root = a
    while parent[root] != root:
        root = parent[root]
    while parent[a] != root:
        parent[a], a = root, parent[a]
    return root


@njit(cache=True, nogil=True, error_model="numpy")
def _edge_facts(faces, n_vertices, labels, start, fill, other, use, parent):
    """``(boundary edges, watertight, winding consistent, pieces)`` of a face array, and the
    piece of every face in ``labels`` (numbered by their lowest face), from the edges grouped
    by their lower vertex (a counting sort): the answers of ``repair._edge_facts``. Scratch
    from the caller (NumPy's pages, see :func:`_grid`): ``start`` (``n_vertices + 1``,
    zeros), ``fill`` (``n_vertices``), ``other`` and ``use`` (3 per face), ``parent`` (one per
    face)."""
    m = faces.shape[0]
    for f in range(m):
        for k in range(3):
            a, b = faces[f, k], faces[f, (k + 1) % 3]
            start[min(a, b) + 1] += 1
    for v in range(n_vertices):
        start[v + 1] += start[v]
    for v in range(n_vertices):
        fill[v] = start[v]
    # other: the higher vertex of each edge use; use: 2 face + whether it goes from the lower
    # vertex to the higher (its direction, so that the winding needs no look-up of the faces)
    for f in range(m):
        for k in range(3):
            a, b = faces[f, k], faces[f, (k + 1) % 3]
            lo = min(a, b)
            other[fill[lo]] = max(a, b)
            use[fill[lo]] = 2 * f + (1 if a < b else 0)
            fill[lo] += 1
    for f in range(m):
        parent[f] = f
    boundary = 0
    two_uses = 0
    winding = True
    for v in range(n_vertices):
        for p in range(start[v], start[v + 1]):
            hi = other[p]
            count = 0
            first = -1
            seen = False
            for q in range(start[v], start[v + 1]):
                if other[q] == hi:
                    if q < p:
                        seen = True         # this edge was counted at its first use
                        break
                    count += 1
                    if count == 2:
                        first = q
            if seen:
                continue
            if count == 1:
                boundary += 1
            elif count == 2:
                two_uses += 1
                ua, ub = use[p], use[first]
                fa, fb = ua >> 1, ub >> 1
                # the first use ends where the second starts: opposite directions (an edge
                # from a vertex to itself ends where it starts, whatever its direction)
                if hi != v and (ua & 1) == (ub & 1):
                    winding = False
                ra, rb = _find(parent, fa), _find(parent, fb)
                if ra != rb:
                    parent[max(ra, rb)] = min(ra, rb)
    # one piece (most meshes): every label 0, without a find per face (random reads: as
    # long as the edge pass at a million faces)
    roots = 0
    for f in range(m):
        roots += parent[f] == f
    if roots == 1:
        for f in range(m):
            labels[f] = 0
        return boundary, two_uses * 2 == 3 * m, winding, 1
    n = 0
    for f in range(m):
        r = _find(parent, f)
        if r == f:
            labels[f] = n
            n += 1
        else:
            labels[f] = labels[r]
    return boundary, two_uses * 2 == 3 * m, winding, n


@njit(cache=True, nogil=True, error_model="numpy")
def _volume_terms(vertices, faces, out):
    """``out[f]``: face ``f``'s term of the enclosed volume (``repair._volume``: trimesh's
    ``mass_properties`` integral, the same arithmetic in the same order, no fused
    multiply-add), summed by the caller with ``np.sum`` (NumPy's pairwise order)."""
    for f in range(faces.shape[0]):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        y0, y1, y2 = vertices[i0, 1], vertices[i1, 1], vertices[i2, 1]
        z0, z1, z2 = vertices[i0, 2], vertices[i1, 2], vertices[i2, 2]
        cross_x = (y1 - y0) * (z2 - z1) - (z1 - z0) * (y2 - y1)
        out[f] = cross_x * (vertices[i0, 0] + vertices[i1, 0] + vertices[i2, 0])


_F2 = _nt.Array(_nt.float64, 2, "C", readonly=True)
_I2 = _nt.Array(_nt.int64, 2, "C", readonly=True)
_I1r = _nt.Array(_nt.int64, 1, "C", readonly=True)
_I1 = _nt.Array(_nt.int64, 1, "C")
_B1 = _nt.Array(_nt.boolean, 1, "C")
#: The one specialisation of each kernel.
_F2w = _nt.Array(_nt.float64, 2, "C")
_I2w = _nt.Array(_nt.int64, 2, "C")
_F1w = _nt.Array(_nt.float64, 1, "C")
_F1r = _nt.Array(_nt.float64, 1, "C", readonly=True)
SIGNATURES = {
    # vertices, faces, then lo, hi, glo, dims (out)
    "_grid_boxes": (_F2, _I2, _F2w, _F2w, _F1w, _I1),
    # faces, lo, hi, glo, inv, dims, then start, face_id, pface, plo, phi, clo (out)
    "_grid_place": (_I2, _F2, _F2, _F1r, _nt.float64, _I1r, _I1, _I1, _I2w, _F2w, _F2w, _I2w),
    # faces j_lo, j_hi, placing, phi, clo, glo, inv, dims, then fill, keys, owner (out)
    "_grid_entries": (_nt.int64, _nt.int64, _nt.boolean, _F2, _I2, _F1r, _nt.float64, _I1r,
                      _I1, _I1, _I1),
    # buckets lo, hi, vertices, faces, labels, flags (out), then the grid's arrays
    "_sweep_buckets": (_nt.int64, _nt.int64, _F2, _I2, _I1r, _B1, _I1, _I1, _I1, _F2w, _F2w,
                       _I2w, _I1, _I1, _nt.int64, _I2w),
    # faces, vertex count, labels (out), then scratch: start, fill, other, use, parent
    "_edge_facts": (_I2, _nt.int64, _I1, _I1, _I1, _I1, _I1, _I1),
    "_volume_terms": (_F2, _I2, _F1w),                    # vertices, faces, terms (out)
}

#: The kernels above, each compiled for its one signature on first use
#: (:mod:`xray_viz.tracing._compile`).
KERNELS = KernelSet(__name__, {"_grid_boxes": _grid_boxes, "_grid_place": _grid_place,
                               "_grid_entries": _grid_entries,
                               "_sweep_buckets": _sweep_buckets, "_edge_facts": _edge_facts,
                               "_volume_terms": _volume_terms}, SIGNATURES)


def compile_kernels() -> list:
    """Compile (or load from numba's cache) every kernel of this module; returns their names
    (for a background process filling the cache)."""
    return KERNELS.compile()


def is_ready() -> bool:
    """Whether every kernel is compiled in this process or in numba's cache (using them then
    costs no compilation)."""
    return KERNELS.is_ready()


def prepare(*, nice: int = 10) -> bool:
    """Start compiling the kernels into numba's cache in a background process, unless they are
    ready (:func:`is_ready`), another process is already compiling them into the same cache,
    or there is no cache to share them through; returns whether one started
    (:meth:`~xray_viz.tracing._compile.KernelSet.fill_cache`).

    Until they are cached, :mod:`xray_viz.meshes.repair` answers with NumPy and pymeshlab,
    so nothing waits for this process: ``xray-viz render`` calls this once its image is
    written, for the next runs.

    Parameters
    ----------
    nice : int, optional
        Added to the background process's niceness (``os.nice``), so that it yields the
        processor to whatever runs next.
    """
    return KERNELS.fill_cache(nice=nice)


def _checked_faces(faces, n_vertices) -> np.ndarray:
    f = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) and (f.min() < 0 or f.max() >= n_vertices):
        raise IndexError(f"face indices outside 0 .. {n_vertices - 1}")
    return f


def edge_facts(faces, n_vertices):
    """``(boundary, watertight, winding, labels, n_pieces)``: what
    :func:`xray_viz.meshes.repair._edge_facts` computes, in one pass over the edges.

    Examples
    --------
    >>> import trimesh
    >>> box = trimesh.creation.box()
    >>> boundary, watertight, winding, labels, n = edge_facts(box.faces, len(box.vertices))
    >>> boundary, watertight, winding, n
    (0, True, True, 1)
    """
    f = _checked_faces(faces, n_vertices)
    m, nv = len(f), int(n_vertices)
    labels = np.empty(m, np.int64)
    boundary, watertight, winding, n = KERNELS.kernel("_edge_facts")(
        f, nv, labels, np.zeros(nv + 1, np.int64), np.empty(nv, np.int64),
        np.empty(3 * m, np.int64), np.empty(3 * m, np.int64), np.empty(m, np.int64))
    return int(boundary), bool(watertight), bool(winding), labels, int(n)


def volume(vertices, faces) -> float:
    """The enclosed volume of a mesh: :func:`xray_viz.meshes.repair._volume`'s float (the
    same terms, summed by ``np.sum``), in one compiled pass over the faces.

    Examples
    --------
    >>> import trimesh
    >>> box = trimesh.creation.box(extents=[2, 3, 4])
    >>> volume(box.vertices, box.faces), float(box.volume)
    (24.0, 24.0)
    """
    v = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = _checked_faces(faces, len(v))
    terms = np.empty(len(f))
    KERNELS.kernel("_volume_terms")(v, f, terms)
    with np.errstate(all="ignore"):
        return float(np.sum(terms) / 6.0)


def _sweep_threads() -> int:
    """Threads of the self-intersection sweep: the library's count (:mod:`xray_viz._threads`)."""
    from xray_viz import _threads

    return _threads.count()


def _pieces(m) -> int:
    """Pieces (threads) to split the grid's entries and the sweep of ``m`` faces into."""
    return max(1, min(_sweep_threads(), m // _PARALLEL_FACES))


def start_grid(vertices, faces):
    """Start building the candidate grid of :func:`self_intersections` on a thread of the
    library's pool (:mod:`xray_viz._threads`), so that it is built while the caller does
    other work that the test waits for (the edge facts and volume of the mesh checks); pass
    what this returns as ``started`` to :func:`self_intersections`, which waits for it, or to
    :func:`discard` if the test is not needed after all. None (nothing started) when the
    kernels are not ready, the mesh has fewer than :data:`_PARALLEL_FACES` faces, there is one
    thread, or a face index or a vertex is invalid (:func:`self_intersections` says so).

    Examples
    --------
    >>> import trimesh
    >>> s = trimesh.creation.icosphere(subdivisions=6)
    >>> _ = compile_kernels()
    >>> started = start_grid(s.vertices, s.faces)
    >>> int(self_intersections(s.vertices, s.faces, started=started).sum())
    0
    """
    if len(faces) < _PARALLEL_FACES or _sweep_threads() < 2 or not is_ready():
        return None
    v = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    try:
        f = _checked_faces(faces, len(v))
    except IndexError:
        return None
    if not np.isfinite(v).all():
        return None
    from xray_viz._threads import pool

    return v, f, pool(2).submit(_grid, v, f, finish=False)


def discard(started) -> None:
    """Wait for a grid of :func:`start_grid` that is not needed (so that it does not hold a
    thread of the pool, nor its memory, beyond the caller's work); None does nothing."""
    if started is not None:
        started[2].exception()


def self_intersections(vertices, faces, labels=None, *, started=None) -> np.ndarray:
    """The faces pymeshlab selects as self-intersecting (see the module docstring).

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (m, 3) int
    labels : (m,) int, optional
        A label per face (the edge-connected piece): only faces crossing a face of the same
        label are flagged.

    started : tuple, optional
        What :func:`start_grid` returned for these ``vertices`` and ``faces`` (its grid is
        waited for instead of built here).

    Returns
    -------
    (m,) bool

    Raises
    ------
    ValueError
        A vertex is not finite (pymeshlab answers those: ``repair.self_intersecting_faces``).

    Examples
    --------
    >>> import trimesh
    >>> a = trimesh.creation.box(extents=[2, 2, 2])
    >>> b = a.copy(); _ = b.apply_translation([1, 0.5, 0.25])
    >>> both = trimesh.util.concatenate([a, b])
    >>> int(self_intersections(a.vertices, a.faces).sum()), int(self_intersections(
    ...     both.vertices, both.faces).sum())
    (0, 12)
    """
    if started is not None:          # checked by start_grid
        v, f, grid = started[0], started[1], _grid_finish(started[2].result())
    else:
        v = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
        f = _checked_faces(faces, len(v))
        if not np.isfinite(v).all():
            raise ValueError("vertices that are not finite")
    lab = (np.zeros(0, np.int64) if labels is None
           else np.ascontiguousarray(labels, dtype=np.int64).reshape(-1))
    flags = np.zeros(len(f), bool)
    if len(f) >= 2:
        if started is None:
            grid = _grid(v, f)
        start, n_buckets = grid[0], len(grid[0]) - 1
        if grid[7][0] == 0:
            return flags
        sweep = KERNELS.kernel("_sweep_buckets")
        # one range of buckets per thread, of about equal numbers of entries
        k = _pieces(len(f))
        cut = [0, *np.searchsorted(start, [start[-1] * j // k for j in range(1, k)]).tolist(),
               n_buckets]
        from xray_viz._threads import run_pieces

        run_pieces(lambda j: sweep(cut[j], cut[j + 1], v, f, lab, flags, *grid), k)
    return flags
