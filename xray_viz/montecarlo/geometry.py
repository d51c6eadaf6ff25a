"""Where is the next boundary, and which body is a photon in: a BVH over the bodies' triangles.

The crossings are the primary engines' watertight test (:func:`xray_viz.tracing.intersect.
watertight_intersect`: the ray's own frame, edge functions whose signs are exact, and the same
tie rule for an edge function that is exactly zero), here in numba: a ray through an edge or a
vertex shared by triangles of one closed surface crosses it exactly once. The exact sign of
``a b - c d`` comes from Dekker's exact products and Shewchuk's exact sums instead of
fractions.

Which body a photon is in follows the hit sweep of :mod:`xray_viz.attenuation`: each photon
carries its entries minus exits per body (the nonzero winding rule), and among the bodies it
is inside the one of highest precedence (nesting, then list order:
:func:`xray_viz.attenuation.body_precedence`) gives the material and scores the energy.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

import xray_viz.tracing._numba_cache  # noqa: F401  (the kernels' one disk cache)
from xray_viz.tracing._primitives import tie_positive

__all__ = ["BVH", "build_bvh", "MAX_TIES", "LEAF_SIZE"]     # and the numba kernels below

#: Leaves hold at most this many triangles: one (a flat node box around one triangle rejects
#: most rays by its slabs alone; see BENCHMARKS.md, "Photon transport: speed").
LEAF_SIZE = 1
#: Most crossings at one ``t`` kept (bodies sharing a surface point).
MAX_TIES = 16
_ERRBOUND = 4.0 * np.finfo(np.float64).eps
_SPLITTER = 134217729.0          # 2**27 + 1, Dekker's split of a double


class BVH(NamedTuple):
    """A bounding-volume hierarchy of triangles, flattened for the numba kernels (a named
    tuple: the kernels take it as one argument).

    Attributes
    ----------
    lo, hi : (N, 3) float
        Node boxes (widened by a few ulps of the scene's size: the slab test is conservative).
    child : (N, 2) int64
        Children of an inner node; ``-1`` for a leaf.
    start, count : (N,) int64
        A leaf's triangles ``order[start:start + count]``.
    v0, v1, v2 : (T, 3) float
        Triangles in leaf order.
    body : (T,) int64
        The body of each triangle (leaf order).
    """

    lo: np.ndarray
    hi: np.ndarray
    child: np.ndarray
    start: np.ndarray
    count: np.ndarray
    v0: np.ndarray
    v1: np.ndarray
    v2: np.ndarray
    body: np.ndarray


def build_bvh(triangles, triangle_body) -> BVH:
    """Build the hierarchy: median splits of the centroids along their widest axis, down to
    leaves of :data:`LEAF_SIZE` triangles, one level of nodes at a time (NumPy).

    Parameters
    ----------
    triangles : (T, 3, 3) float
        Every triangle of every body (``Scene.triangles``).
    triangle_body : (T,) int

    Examples
    --------
    >>> import trimesh
    >>> box = trimesh.creation.box(extents=[2, 2, 2])
    >>> bvh = build_bvh(box.triangles, np.zeros(12, int))
    >>> int(bvh.count.sum()), bvh.v0.shape
    (12, (12, 3))
    """
    tri = np.ascontiguousarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    n = len(tri)
    tri_lo = tri.min(axis=1)
    tri_hi = tri.max(axis=1)
    cen = 0.5 * (tri_lo + tri_hi)
    order = np.arange(n)
    scale = float(np.abs(tri).max()) if n else 1.0
    pad = 64 * np.finfo(float).eps * max(scale, 1.0)
    size = max(2 * n - 1, 1)
    lo, hi = np.zeros((size, 3)), np.zeros((size, 3))
    child = np.full((size, 2), -1, np.int64)
    start, count = np.zeros(size, np.int64), np.zeros(size, np.int64)

    def ranges(s, e, values, ufunc):
        """``ufunc`` over ``values[s_k:e_k]`` for each range (non-empty, in increasing
        order), as rows."""
        at = np.ravel([s, e], order="F")
        out = np.empty((len(s), values.shape[1]))
        for k in range(values.shape[1]):            # 1D columns: reduceat is slow on 2D
            col = np.concatenate([values[:, k], values[:1, k]])
            out[:, k] = ufunc.reduceat(col, at)[::2]
        return out

    def boxes(nodes, s, e):
        lo[nodes] = ranges(s, e, tri_lo[order], np.minimum) - pad
        hi[nodes] = ranges(s, e, tri_hi[order], np.maximum) + pad
        start[nodes] = s
        count[nodes] = e - s

    # level by level (vectorised over a level's nodes): each node's triangles split at their
    # centroids' median along the centroids' widest axis
    nodes, seg_s, seg_e = np.array([0]), np.array([0]), np.array([n])
    used = 1
    if n:
        boxes(nodes, seg_s, seg_e)
    while len(nodes):
        split = seg_e - seg_s > LEAF_SIZE
        nodes, seg_s, seg_e = nodes[split], seg_s[split], seg_e[split]
        if not len(nodes):
            break
        c = cen[order]
        axis = np.argmax(ranges(seg_s, seg_e, c, np.maximum)
                         - ranges(seg_s, seg_e, c, np.minimum), axis=1)
        length = seg_e - seg_s
        seg = np.repeat(np.arange(len(nodes)), length)
        idx = np.arange(length.sum()) - np.repeat(np.cumsum(length) - length, length) \
            + np.repeat(seg_s, length)
        key = c[idx, axis[seg]]
        perm = np.lexsort((key, seg))
        order[idx] = order[idx[perm]]
        mid = (seg_s + seg_e) // 2
        left = used + 2 * np.arange(len(nodes))
        right = left + 1
        used += 2 * len(nodes)
        child[nodes, 0], child[nodes, 1] = left, right
        boxes(left, seg_s, mid)
        boxes(right, mid, seg_e)
        count[nodes] = 0
        # the next level in order of position (reduceat's ranges: no work between them)
        nodes = np.ravel([left, right], order="F")
        seg_s = np.ravel([seg_s, mid], order="F")
        seg_e = np.ravel([mid, seg_e], order="F")
    lo, hi, child, start, count = lo[:used], hi[:used], child[:used], start[:used], count[:used]
    tri = tri[order]
    return BVH(lo=lo, hi=hi, child=child, start=start, count=count,
               v0=np.ascontiguousarray(tri[:, 0]), v1=np.ascontiguousarray(tri[:, 1]),
               v2=np.ascontiguousarray(tri[:, 2]),
               body=np.asarray(triangle_body, np.int64)[order])


# --- exact signs (numba) -------------------------------------------------------------------

@numba.njit(inline="always")
def _two_product(a, b):
    p = a * b
    c = _SPLITTER * a
    ah = c - (c - a)
    al = a - ah
    c = _SPLITTER * b
    bh = c - (c - b)
    bl = b - bh
    e = ((ah * bh - p) + ah * bl + al * bh) + al * bl
    return p, e


@numba.njit(inline="always")
def _two_sum(a, b):
    x = a + b
    bv = x - a
    av = x - bv
    return x, (a - av) + (b - bv)


@numba.njit(inline="always")
def _two_diff(a, b):
    x = a - b
    bv = a - x
    av = x + bv
    return x, (a - av) + (bv - b)


@numba.njit(cache=True, nogil=True)
def exact_sign(a, b, c, d):
    """Exact sign of ``a b - c d`` (doubles, no overflow): Dekker's exact products and
    Shewchuk's Two_Two_Diff; the sign of the expansion is its leading non-zero term's."""
    p1, e1 = _two_product(a, b)
    p2, e2 = _two_product(c, d)
    # Two_One_Diff(p1, e1, e2) -> j, z0, x0
    i, x0 = _two_diff(e1, e2)
    j, z0 = _two_sum(p1, i)
    # Two_One_Diff(j, z0, p2) -> x3, x2, x1
    i2, x1 = _two_diff(z0, p2)
    x3, x2 = _two_sum(j, i2)
    for x in (x3, x2, x1, x0):
        if x > 0:
            return 1
        if x < 0:
            return -1
    return 0


@numba.njit(inline="always")
def _edge_sign(a, b, c, d, approx, ex, ey):
    """Sign of ``a b - c d`` (rounded ``approx``), exact near zero; a zero resolved by the
    tie rule (``xray_viz.tracing._primitives.tie_positive``, edge vector ``ex, ey``)."""
    s = 0
    if abs(approx) > _ERRBOUND * (abs(a * b) + abs(c * d)):
        s = 1 if approx > 0 else -1
    else:
        s = exact_sign(a, b, c, d)
    if s == 0:
        s = 1 if tie_positive(ex, ey) else -1
    return s


@numba.njit(cache=True, nogil=True)
def ray_frame(d):
    """``(kx, ky, kz, sx, sy, sz)``: the shear that makes the ray the z axis (Woop et al.)."""
    ax, ay, az = abs(d[0]), abs(d[1]), abs(d[2])
    kz = 0
    if ay > ax and ay >= az:
        kz = 1
    elif az > ax and az > ay:
        kz = 2
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    if d[kz] < 0.0:
        kx, ky = ky, kx
    return kx, ky, kz, d[kx] / d[kz], d[ky] / d[kz], 1.0 / d[kz]


@numba.njit(cache=True, nogil=True)
def _triangle(o, d, v0, v1, v2, kx, ky, kz, sx, sy, sz):
    """``(t, entering)`` of the watertight test of one triangle (t = inf: no hit)."""
    qz = v0[kz] - o[kz]
    ax = (v0[kx] - o[kx]) - sx * qz
    ay = (v0[ky] - o[ky]) - sy * qz
    az = sz * qz
    qz = v1[kz] - o[kz]
    bx = (v1[kx] - o[kx]) - sx * qz
    by = (v1[ky] - o[ky]) - sy * qz
    bz = sz * qz
    qz = v2[kz] - o[kz]
    cx = (v2[kx] - o[kx]) - sx * qz
    cy = (v2[ky] - o[ky]) - sy * qz
    cz = sz * qz
    u = cx * by - cy * bx
    v = ax * cy - ay * cx
    w = bx * ay - by * ax
    su = _edge_sign(cx, by, cy, bx, u, cx - bx, cy - by)
    sv = _edge_sign(ax, cy, ay, cx, v, ax - cx, ay - cy)
    if su != sv:
        return np.inf, False
    sw = _edge_sign(bx, ay, by, ax, w, bx - ax, by - ay)
    if sv != sw:
        return np.inf, False
    det = u + v + w
    t = (u * az + v * bz + w * cz) / det
    if not math.isfinite(t):                    # a sliver: the plane equation
        e1x, e1y, e1z = v1[0] - v0[0], v1[1] - v0[1], v1[2] - v0[2]
        e2x, e2y, e2z = v2[0] - v0[0], v2[1] - v0[1], v2[2] - v0[2]
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        den = nx * d[0] + ny * d[1] + nz * d[2]
        t = (nx * (v0[0] - o[0]) + ny * (v0[1] - o[1]) + nz * (v0[2] - o[2])) / den
        if not math.isfinite(t):
            return np.inf, False
    return t, su > 0


@numba.njit(inline="always")
def _slab(lo, hi, node, o, inv0, inv1, inv2, t_min, best):
    """Entry ``t`` of the ray into a node's (padded, so conservative) box; inf if it misses
    the box or meets it only outside ``(t_min, best]``."""
    t0 = (lo[node, 0] - o[0]) * inv0
    t1 = (hi[node, 0] - o[0]) * inv0
    tn = min(t0, t1)
    tf = max(t0, t1)
    t0 = (lo[node, 1] - o[1]) * inv1
    t1 = (hi[node, 1] - o[1]) * inv1
    tn = max(tn, min(t0, t1))
    tf = min(tf, max(t0, t1))
    t0 = (lo[node, 2] - o[2]) * inv2
    t1 = (hi[node, 2] - o[2]) * inv2
    tn = max(tn, min(t0, t1))
    tf = min(tf, max(t0, t1))
    if tn > tf or tf < t_min or tn > best:
        return np.inf
    return tn


@numba.njit(cache=True, nogil=True)
def next_crossing(o, d, t_min, t_max, bvh, stack, tie_body, tie_enter):
    """The nearest surface crossings of the ray ``o + t d`` with ``t_min < t <= t_max`` of
    the triangles of ``bvh`` (:class:`BVH`).

    Returns ``(t, n)``: the crossings' ``t`` (inf if none) and how many there are at that
    very ``t`` (their bodies and directions in ``tie_body[:n]``, ``tie_enter[:n]``; at most
    ``MAX_TIES``). ``stack``: scratch, (64,) int64.
    """
    lo, hi, child, start, count, v0, v1, v2, tri_body = bvh
    kx, ky, kz, sx, sy, sz = ray_frame(d)
    inv0 = 1.0 / d[0] if d[0] != 0.0 else 1e300
    inv1 = 1.0 / d[1] if d[1] != 0.0 else 1e300
    inv2 = 1.0 / d[2] if d[2] != 0.0 else 1e300
    best = t_max
    found = np.inf
    n = 0
    top = 0
    if lo.shape[0] == 0 or count.shape[0] == 0:
        return found, 0
    if _slab(lo, hi, 0, o, inv0, inv1, inv2, t_min, best) == np.inf:
        return found, 0
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        node = stack[top]
        c = child[node, 0]
        if c >= 0:
            # nearer child last on the stack (visited first): the first hits shrink `best`
            c1 = child[node, 1]
            t0 = _slab(lo, hi, c, o, inv0, inv1, inv2, t_min, best)
            t1 = _slab(lo, hi, c1, o, inv0, inv1, inv2, t_min, best)
            if t0 <= t1:
                if t1 < np.inf:
                    stack[top] = c1
                    top += 1
                if t0 < np.inf:
                    stack[top] = c
                    top += 1
            else:
                if t0 < np.inf:
                    stack[top] = c
                    top += 1
                stack[top] = c1
                top += 1
            continue
        s = start[node]
        for k in range(s, s + count[node]):
            t, enter = _triangle(o, d, v0[k], v1[k], v2[k], kx, ky, kz, sx, sy, sz)
            if not (t > t_min and t <= best and t < np.inf):
                continue
            if t < found:
                found = t
                best = t
                n = 0
            if n < tie_body.shape[0]:
                tie_body[n] = tri_body[k]
                tie_enter[n] = enter
                n += 1
    return found, n


@numba.njit(cache=True, nogil=True)
def region_of(inside, rank_order):
    """The body whose material fills a point: the highest precedence among the bodies with a
    positive count in ``inside`` (``rank_order``: bodies by decreasing precedence); -1 if
    none."""
    for k in range(rank_order.shape[0]):
        b = rank_order[k]
        if inside[b] > 0:
            return b
    return -1


@numba.njit(cache=True, nogil=True)
def winners(points, bvh, rank_order, n_bodies):
    """(n,) int: the body whose material fills each point (-1: none), by the same rule as the
    transport: along a fixed ray from the point to infinity, exits minus entries per body
    (1 inside a closed body) of the triangles of ``bvh`` (:class:`BVH`), then the
    precedence."""
    out = np.empty(points.shape[0], np.int64)
    inside = np.zeros(max(n_bodies, 1), np.int64)
    stack = np.empty(128, np.int64)
    tie_body = np.empty(MAX_TIES, np.int64)
    tie_enter = np.empty(MAX_TIES, np.bool_)
    d = np.array([0.5773502691896258, 0.5773502691896257, 0.5773502691896259])
    d = d / math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    d[0] += 1e-3                                  # off the axes and diagonals of boxes
    d = d / math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    for i in range(points.shape[0]):
        inside[:] = 0
        o = points[i]
        t = 0.0
        while True:
            t, n = next_crossing(o, d, t, np.inf, bvh, stack, tie_body, tie_enter)
            if n == 0:
                break
            for k in range(n):
                inside[tie_body[k]] += -1 if tie_enter[k] else 1
        out[i] = region_of(inside, rank_order)
    return out
