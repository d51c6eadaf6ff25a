"""Compiled kernels of the fast engine (numba): projection, triangle set-up, footprint raster.

Everything here works on a *fine grid*: the detector's rays (with ``n x n`` supersampling, the
sub-rays) sit at the integer points ``(X, Y)``, ``0 <= X < n W``, ``0 <= Y < n H``, X along
``HO`` and Y along ``VE``. Projected vertices are snapped to fixed point, ``2**-FRAC_BITS`` of a
fine-grid step, and every coverage decision is an exact integer edge function with a tie rule
(a symbolic perturbation of the sample point), so a ray through a shared edge or vertex is
covered by exactly one triangle of each surface sheet. See :mod:`xray_viz.tracing.fast`.

Vertices are coordinate-major, ``V`` of shape ``(3, n_vertices)`` (x, y and z each contiguous),
as the per-mesh set-up (:func:`spatial_order`) writes them: the projection's loops then read
them with plain vector loads (``benchmarks/notes/kernels.md``); a triangle's plane reads its
three vertices' coordinates from the three rows.

This module holds the kernels, the named tuples they take and their one signature each
(:data:`SIGNATURES`, compiled through :data:`KERNELS`, :mod:`xray_viz.tracing._compile`); the
engine calls them through :mod:`xray_viz.tracing._raster_calls`, which normalises the
arguments and splits each kernel's range over the library's threads.
"""

from __future__ import annotations

import os
from typing import NamedTuple

import numba
import numpy as np
from numba import njit
from numba.extending import intrinsic

# Imported before the kernels are defined: it gives them their disk cache.
from xray_viz.tracing import _numba_cache  # noqa: F401
from xray_viz.tracing._primitives import tie_positive

# An old TBB (Open3D brings one) makes numba warn when it tries its TBB threading layer first;
# OpenMP or numba's own work queue serve these kernels equally well. A user's choice wins.
if not {"NUMBA_THREADING_LAYER", "NUMBA_THREADING_LAYER_PRIORITY"} & set(os.environ):
    numba.config.THREADING_LAYER_PRIORITY = ["omp", "workqueue", "tbb"]

#: Fixed-point fraction bits of a projected vertex (units of a fine-grid step). The snapped
#: geometry is watertight whatever this is; it moves vertices by at most 2**-(FRAC_BITS+1)
#: of a grid step, which bounds the path-length error of rays grazing a silhouette.
FRAC_BITS = 22
ONE = 1 << FRAC_BITS
#: Projected coordinates (fine-grid steps) beyond this cannot be snapped safely (2**57 units).
COORD_LIMIT = float(2 ** (57 - FRAC_BITS))
#: A triangle whose snapped bounding box is smaller than this (fixed-point units, i.e. 256
#: grid steps) uses plain int64 edge functions (|E| < 2**61); larger ones use exact limb
#: arithmetic (sign of a 128-bit product difference).
SAFE_EXTENT = 1 << 30
_MASK30 = (1 << 30) - 1

# Triangle set-up status codes (times the orientation, +-1).
SKIP = 0
SMALL = 1
GIANT = 2
ERR_STRADDLE = -100
ERR_TOO_CLOSE = -101


#: Cell code of a vertex that never lets a triangle be culled by its cell codes.
NO_CODE = 1 | (1 << 16)
#: Largest fine-grid width or height for which cell codes are written (15 bits per axis).
CODE_MAX_SAMPLES = 16382


@njit(cache=True, nogil=True, error_model="numpy")
def _axis_code(x, n):
    """Cell code of a snapped coordinate on an axis of ``n`` samples (0 .. n - 1): 0 left of
    sample 0, ``2 n + 2`` right of sample ``n - 1``, ``2 k + 2`` strictly between samples k and
    k + 1, ``2 k + 3`` exactly on sample k. Three equal even codes: no sample in between.
    Branch free (selects), so that the projection's loop over vertices is vectorised."""
    c = 2 * (x >> FRAC_BITS) + np.int64((x & (ONE - 1)) == 0) + 2
    c = np.int64(2 * n + 2) if x > (n - 1) * ONE else c
    return np.int64(0) if x < 0 else c


def first_use_rank(V, flat_faces, spatial, rank, Vout, Fout, code, order, tmp, cnt, hist):
    """New number of each vertex: its rank in order of first appearance in ``flat_faces``
    (vertices used by no face follow, in their previous order), into ``rank``.

    With ``spatial``, the faces (``flat_faces`` read as triangles) are first sorted along the
    Morton (Z-curve) order of their vertices: each triangle by the first, in Morton order, of
    its vertices (stable: ties keep the face order), the vertices by the Morton code of their
    position quantised to 1024 steps per axis of the bounding box (a stable LSD radix sort,
    ties keep the vertex order); vertices used by no face then follow in Morton order. Then
    ``Vout[:, rank[i]] = V[i]`` (``Vout`` coordinate-major, ``(3, n)``) and ``Fout`` receives
    the faces, renumbered, in the order visited (outputs of length 0 are not written; with
    ``spatial``, ``Fout`` is needed). Indices read from memory are made unsigned where they
    index (no negative-index fix-up, see :func:`_faces`). Scratch (``spatial`` only,
    int64): ``code``, ``order`` (V), ``tmp`` (max(V, T)), ``cnt`` (V + 1), ``hist`` (3 x 1025,
    zeros).
    """
    nv = rank.shape[0]
    nf = flat_faces.shape[0]
    if spatial:
        # Morton code of each vertex: bit b of axis a at bit 3 b + a (10 bits per axis).
        lo0, lo1, lo2 = V[0, 0], V[0, 1], V[0, 2]
        hi0, hi1, hi2 = lo0, lo1, lo2
        for i in range(nv):
            lo0, hi0 = min(lo0, V[i, 0]), max(hi0, V[i, 0])
            lo1, hi1 = min(lo1, V[i, 1]), max(hi1, V[i, 1])
            lo2, hi2 = min(lo2, V[i, 2]), max(hi2, V[i, 2])
        d0, d1, d2 = max(hi0 - lo0, 1e-300), max(hi1 - lo1, 1e-300), max(hi2 - lo2, 1e-300)
        for i in range(nv):
            c = 0
            for a in range(3):
                x = (V[i, a] - (lo0 if a == 0 else lo1 if a == 1 else lo2)) / (
                    d0 if a == 0 else d1 if a == 1 else d2) * 1023
                x = np.int64(np.uint64(x)) & 1023           # bits b -> 3 b (magic masks)
                x = (x | (x << 16)) & 0x30000FF
                x = (x | (x << 8)) & 0x300F00F
                x = (x | (x << 4)) & 0x30C30C3
                c |= ((x | (x << 2)) & 0x9249249) << a
            code[i] = c
            order[i] = i
            for p in range(3):
                hist[p, ((c >> (10 * p)) & 1023) + 1] += 1
        # Stable LSD radix sort of the codes, 10 bits a pass (order <-> tmp).
        for p in range(3):
            src = order if p != 1 else tmp
            dst = tmp if p != 1 else order
            for j in range(1024):
                hist[p, j + 1] += hist[p, j]
            for j in range(nv):
                i = src[j]
                b = ((code[np.uint64(i)] >> (10 * p)) & 1023)
                dst[np.uint64(hist[p, b])] = i
                hist[p, b] += 1
        for j in range(nv):               # tmp: the Morton order; code: each vertex's rank
            code[np.uint64(tmp[j])] = j
            order[j] = tmp[j]
        # Faces by the Morton rank of their first vertex in that order (stable counting sort,
        # each face's key kept in tmp for the second pass), written where they go into Fout
        # (the faces read in order), renumbered there below.
        for t in range(nf // 3):
            m = min(code[np.uint64(flat_faces[3 * t])],
                    min(code[np.uint64(flat_faces[3 * t + 1])],
                        code[np.uint64(flat_faces[3 * t + 2])]))
            cnt[np.uint64(m + 1)] += 1
            tmp[t] = m
        for j in range(nv):
            cnt[j + 1] += cnt[j]
        for t in range(nf // 3):
            m = np.uint64(tmp[t])
            j = cnt[m]
            cnt[m] += 1
            for c in range(3):
                Fout[np.uint64(3 * j + c)] = flat_faces[3 * t + c]
    for i in range(nv):
        rank[i] = -1
    # Each vertex numbered at its first use, and each face written renumbered in the same
    # pass (a vertex's number is final once given): one visit of the faces, not two.
    k = 0
    if spatial:
        for j in range(nf):
            v = np.uint64(Fout[j])
            if rank[v] < 0:
                rank[v] = k
                k += 1
            Fout[j] = rank[v]
    else:
        write = Fout.shape[0] != 0
        for j in range(nf):
            v = np.uint64(flat_faces[j])
            if rank[v] < 0:
                rank[v] = k
                k += 1
            if write:
                Fout[j] = rank[v]
    for j in range(nv):
        v = np.uint64(order[j] if spatial else j)
        if rank[v] < 0:
            rank[v] = k
            k += 1
    for i in range(Vout.shape[1]):
        r = np.uint64(rank[i])          # unsigned: no negative-index fix-up (see _faces)
        Vout[0, r] = V[i, 0]
        Vout[1, r] = V[i, 1]
        Vout[2, r] = V[i, 2]


# (named first_use_rank in numba's cache files; the entry below is first_use_rank)
_first_use_rank = njit(cache=True, nogil=True, error_model="numpy")(first_use_rank)


#: Vertices a block of the projection (its scratch rows stay in the first-level cache).
_PROJ_BLOCK = 256
_LOW63 = np.int64(0x7FFFFFFFFFFFFFFF)
_KEY_MAX = _LOW63
_KEY_MIN = np.int64(-_LOW63 - 1)


def depth_key(w):
    """``int64`` keys in the order of the float64 depths ``w`` (and back, the same map):
    the sign-magnitude bits turned two's complement, so that a min or max of integers (which
    LLVM vectorises, unlike a float one with NaN rules) is the min or max of the floats.

    Examples
    --------
    >>> import numpy as np
    >>> k = depth_key(np.array([-2.0, -0.5, 0.0, 0.5, 3.0]))
    >>> bool(np.all(np.diff(k) > 0))
    True
    >>> depth_key(k.view(np.float64)).view(np.float64).tolist()
    [-2.0, -0.5, 0.0, 0.5, 3.0]
    """
    bits = np.asarray(w, np.float64).view(np.int64)
    return bits ^ ((bits >> 63) & _LOW63)


@njit(cache=True, nogil=True, error_model="numpy")
def _project_vertices(lo, hi, V, view, XY, w, huge, K):
    """Project and snap vertices: fine-grid coordinates ``x = sx * (rel.eu) [/ w] + bx``
    (:class:`Projection`); into ``XY``, ``w``, ``huge`` and ``K`` (:class:`Projected`'s).

    ``K`` receives each vertex's cell code (x code in bits 0-15, y code in bits 16-31, see
    :func:`_axis_code`): a triangle whose three vertices have the same even x (or y) code lies
    strictly between two columns (rows) of samples, or outside the grid, and covers no sample.

    Returns ``(kmin, kmax, odd)``: the :func:`depth_key` of the least and largest depth of the
    vertices ``lo .. hi - 1`` (NaN depths left out; ``kmin > kmax`` when there is none) and
    whether one of them is huge or has a NaN depth (what decides the raster's ``depth_ok``,
    without another pass over ``w`` and ``huge``).

    By blocks of :data:`_PROJ_BLOCK` vertices, in loops that LLVM vectorises (the divisions,
    the snapping, the codes and the depth range: no branch in them); the few vertices
    that cannot be snapped (huge, or behind a point source) are written again after their
    block. The same operations in the same order as one scalar loop: the same bits.
    """
    r0, f, eu, ev, sx, bx, sy, by, perspective, nW, nH = view
    codes = nW <= CODE_MAX_SAMPLES and nH <= CODE_MAX_SAMPLES
    # The frame read once: numba cannot prove the outputs do not alias it, so it would
    # reload every component for every vertex.
    o0, o1, o2 = r0[0], r0[1], r0[2]
    f0, f1, f2 = f[0], f[1], f[2]
    u0, u1, u2 = eu[0], eu[1], eu[2]
    v0, v1, v2 = ev[0], ev[1], ev[2]
    xs = np.empty(_PROJ_BLOCK)
    ys = np.empty(_PROJ_BLOCK)
    xi = np.empty(_PROJ_BLOCK, np.int64)
    yi = np.empty(_PROJ_BLOCK, np.int64)
    wk = w.view(np.int64)
    kmin = _KEY_MAX
    kmax = _KEY_MIN
    n_odd = 0
    for b0 in range(lo, hi, _PROJ_BLOCK):
        m = min(_PROJ_BLOCK, hi - b0)
        # Slices of the block: indices from 0 are known not to wrap around (vectorisable).
        V0 = V[0, b0:b0 + m]
        V1 = V[1, b0:b0 + m]
        V2 = V[2, b0:b0 + m]
        wb = w[b0:b0 + m]
        kb = wk[b0:b0 + m]
        XYb = XY[b0:b0 + m]
        hb = huge[b0:b0 + m]
        Kb = K[b0:b0 + m]
        if perspective:
            for j in range(m):
                rx = V0[j] - o0
                ry = V1[j] - o1
                rz = V2[j] - o2
                wi = rx * f0 + ry * f1 + rz * f2
                a = rx * u0 + ry * u1 + rz * u2
                b = rx * v0 + ry * v1 + rz * v2
                wb[j] = wi
                ahead = wi > 0.0
                xs[j] = sx * (a / wi) + bx if ahead else np.inf
                ys[j] = sy * (b / wi) + by if ahead else np.inf
        else:
            for j in range(m):
                rx = V0[j] - o0
                ry = V1[j] - o1
                rz = V2[j] - o2
                wb[j] = rx * f0 + ry * f1 + rz * f2
                xs[j] = sx * (rx * u0 + ry * u1 + rz * u2) + bx
                ys[j] = sy * (rx * v0 + ry * v1 + rz * v2) + by
        n_huge = 0
        for j in range(m):
            x = xs[j]
            y = ys[j]
            ok = (abs(x) < COORD_LIMIT) & (abs(y) < COORD_LIMIT)
            xi[j] = np.int64(np.floor((x if ok else 0.0) * ONE + 0.5))
            yi[j] = np.int64(np.floor((y if ok else 0.0) * ONE + 0.5))
            n_huge += np.int64(not ok)
        # One output a loop, the choice of codes outside the loops: one loop with ``if codes``
        # in it is slower (``benchmarks/notes/kernels.md``).
        for j in range(m):
            XYb[j, 0] = xi[j]
            XYb[j, 1] = yi[j]
        for j in range(m):
            hb[j] = False
        if codes:
            for j in range(m):
                Kb[j] = np.int32(_axis_code(xi[j], nW) | (_axis_code(yi[j], nH) << 16))
        else:
            for j in range(m):
                Kb[j] = NO_CODE
        for j in range(m):
            bits = kb[j]
            key = bits ^ ((bits >> 63) & _LOW63)          # depth_key
            nan = wb[j] != wb[j]
            kmin = min(kmin, _KEY_MAX if nan else key)
            kmax = max(kmax, _KEY_MIN if nan else key)
            n_odd += np.int64(nan)
        if n_huge:
            n_odd += n_huge
            for j in range(m):
                x = xs[j]
                y = ys[j]
                if not (abs(x) < COORD_LIMIT and abs(y) < COORD_LIMIT):
                    # Keep the float position (clamped) for culling only.
                    XYb[j, 0] = (np.int64(max(min(x, COORD_LIMIT), -COORD_LIMIT) * ONE)
                                 if x == x else 0)
                    XYb[j, 1] = (np.int64(max(min(y, COORD_LIMIT), -COORD_LIMIT) * ONE)
                                 if y == y else 0)
                    hb[j] = True
                    Kb[j] = NO_CODE
    return kmin, kmax, n_odd > 0


@njit(cache=True, nogil=True, error_model="numpy")
def _split30(x):
    return x >> 30, x & _MASK30


@njit(cache=True, nogil=True, error_model="numpy")
def exact_cross_sign(a, b, c, d):
    """Exact sign of ``a*b - c*d`` for int64 inputs of magnitude below 2**60."""
    ah, al = _split30(a)
    bh, bl = _split30(b)
    ch, cl = _split30(c)
    dh, dl = _split30(d)
    dH = ah * bh - ch * dh
    dM = (ah * bl + al * bh) - (ch * dl + cl * dh)
    dL = al * bl - cl * dl
    dM += dL >> 30
    r = dL & _MASK30
    dH += dM >> 30
    r2 = dM & _MASK30
    if dH > 0:
        return 1
    if dH < 0:
        return -1
    if r2 > 0 or r > 0:
        return 1
    return 0


# The coverage primitive, written once: a fine-grid sample ``p`` (fixed point) is inside the
# projected triangle ``a, b, c`` of orientation ``o`` (+-1) when each edge function
# ``E_k = o * (e_k x (p - start of edge k))`` (:func:`_edge_function`, edges a->b, b->c, c->a:
# :func:`_edges`) is at least the edge's tie bias (:func:`_tie_biases`: 0 or 1, so that a sample
# exactly on an edge shared by two triangles belongs to one of them). SMALL triangles evaluate
# the edge functions in int64 (stepped along a row by the callers), GIANT ones take their exact
# signs (:func:`_inside_exact`). Scalars only, so that LLVM inlines every one of them.


@njit(cache=True, nogil=True, error_model="numpy")
def _edges(ax, ay, bx, by, cx, cy):
    """The edge vectors ``b - a``, ``c - b``, ``a - c`` of a projected triangle, as
    ``(e0x, e0y, e1x, e1y, e2x, e2y)``."""
    return bx - ax, by - ay, cx - bx, cy - by, ax - cx, ay - cy


@njit(cache=True, nogil=True, error_model="numpy")
def _orientation(e0x, e0y, ax, ay, cx, cy, small):
    """Sign (+-1, 0 for no area) of the projected triangle's area ``e0 x (c - a)``: int64 for
    a SMALL triangle, exact limbs otherwise."""
    if small:
        area = e0x * (cy - ay) - e0y * (cx - ax)
        return np.int64(1) if area > 0 else (np.int64(-1) if area < 0 else np.int64(0))
    return np.int64(exact_cross_sign(e0x, cy - ay, e0y, cx - ax))


@njit(cache=True, nogil=True, error_model="numpy")
def _tie_biases(o, e0x, e0y, e1x, e1y, e2x, e2y):
    """The tie rule: per edge, the least edge function (times ``o``) of a covered sample, 0
    where a sample exactly on the edge is inside, else 1. ``o`` times an edge function is the
    edge function of the edge ``o e``, whose tie (``tie_positive``) decides."""
    return (0 if tie_positive(o * e0x, o * e0y) else 1,
            0 if tie_positive(o * e1x, o * e1y) else 1,
            0 if tie_positive(o * e2x, o * e2y) else 1)


@njit(cache=True, nogil=True, error_model="numpy")
def _edge_function(ex, ey, dx, dy):
    """``e x d = ex * dy - ey * dx``: the edge function of edge ``e`` at the sample ``d`` away
    from the edge's start (int64; exact when the triangle is SMALL)."""
    return ex * dy - ey * dx


@njit(cache=True, nogil=True, error_model="numpy")
def _inside_exact(o, px, py, corners, edges, biases):
    """Whether sample ``(px, py)`` is inside a GIANT triangle, with the tie rule: each edge
    function's exact sign (:func:`exact_cross_sign`) times ``o`` at least its bias.
    ``corners`` ``(ax, ay, bx, by, cx, cy)``, ``edges`` :func:`_edges`'s and ``biases``
    :func:`_tie_biases`'."""
    ax, ay, bx, by, cx, cy = corners
    e0x, e0y, e1x, e1y, e2x, e2y = edges
    bias0, bias1, bias2 = biases
    return (o * exact_cross_sign(e0x, py - ay, e0y, px - ax) >= bias0
            and o * exact_cross_sign(e1x, py - by, e1y, px - bx) >= bias1
            and o * exact_cross_sign(e2x, py - cy, e2y, px - cx) >= bias2)


@njit(cache=True, nogil=True, error_model="numpy")
def _side_value(V, i, r0, planes, k):
    """``n . (V[:, i] - r0) - c`` for side plane ``k`` of the beam, and its rounding scale."""
    dx = V[0, i] - r0[0]
    dy = V[1, i] - r0[1]
    dz = V[2, i] - r0[2]
    nx = planes[k, 0]
    ny = planes[k, 1]
    nz = planes[k, 2]
    c = planes[k, 3]
    return (nx * dx + ny * dy + nz * dz - c,
            abs(nx * dx) + abs(ny * dy) + abs(nz * dz) + abs(c))


@njit(cache=True, nogil=True, error_model="numpy")
def beyond_side(V, i0, i1, i2, r0, planes):
    """True when triangle (i0, i1, i2) lies wholly outside one of the beam's side planes
    (rows of ``planes``, see :func:`xray_viz.attenuation.beam_planes`): no ray meets it.

    Decides whether a triangle crossing the plane of the source (which cannot be projected)
    is harmless; the margin (1e-12 relative) keeps doubtful triangles inside.
    """
    for k in range(planes.shape[0]):
        s0, m0 = _side_value(V, i0, r0, planes, k)
        s1, m1 = _side_value(V, i1, r0, planes, k)
        s2, m2 = _side_value(V, i2, r0, planes, k)
        if s0 > 1e-12 * m0 and s1 > 1e-12 * m1 and s2 > 1e-12 * m2:
            return True
    return False


@njit(cache=True, nogil=True, error_model="numpy")
def _between_samples(ka, kb, kc):
    """Whether a triangle whose vertices have the cell codes ``ka``, ``kb``, ``kc``
    (:func:`_axis_code`, x in bits 0-15, y in 16-31) covers no sample: the three share an
    even code on an axis (strictly between two sample columns or rows, or off the grid on one
    side). Branch free, scalars only (inlined)."""
    d = (ka ^ kb) | (ka ^ kc)
    return (((d & 0xFFFF) | (ka & 1)) == 0) | (((d >> 16) | ((ka >> 16) & 1)) == 0)


@njit(cache=True, nogil=True, error_model="numpy")
def _i32(x):
    """``x`` (which the caller knows to fit in 32 bits) through int32, so that LLVM knows a
    product of two of them needs only a 32 x 32 -> 64-bit multiply. Scalars only (inlined)."""
    return np.int64(np.int32(x))


@njit(cache=True, nogil=True, error_model="numpy")
def _sample_box(ax, ay, bx, by, cx, cy, nW, nH):
    """``(xmin, xmax, ymin, ymax, X0, X1, Y0, Y1)``: the snapped bounding box of a projected
    triangle and the fine-grid samples inside it, clipped to the grid (empty when ``X0 > X1``
    or ``Y0 > Y1``). Scalars only (inlined)."""
    xmin = min(ax, min(bx, cx))
    xmax = max(ax, max(bx, cx))
    ymin = min(ay, min(by, cy))
    ymax = max(ay, max(by, cy))
    X0 = max(-((-xmin) >> FRAC_BITS), 0)
    X1 = min(xmax >> FRAC_BITS, nW - 1)
    Y0 = max(-((-ymin) >> FRAC_BITS), 0)
    Y1 = min(ymax >> FRAC_BITS, nH - 1)
    return xmin, xmax, ymin, ymax, X0, X1, Y0, Y1


@njit(cache=True, nogil=True, error_model="numpy")
def _cull_triangles(lo, hi, mesh, cull, status, box, kept, counts):
    """Per triangle of ``mesh`` (:class:`Projected`): status (SKIP, SMALL or GIANT times the
    orientation, +-1, or an error code) and sample bounding box (the beam: :class:`Cull`).

    Only triangles that can cover a sample get a box; ``status`` is written for all. A triangle
    crossing the plane of the source is an error (ERR_STRADDLE) unless it lies wholly outside
    one of the beam's side ``planes`` (:func:`beyond_side`).

    When ``depth_ok`` (every vertex strictly between the source and the detector planes, none
    huge: no error possible), a first branch-free pass by blocks of ``_BLOCK`` skips the
    triangles whose vertices' cell codes ``K`` say they cover no sample (as their box would:
    the same status), as :func:`_raster_direct` does. ``kept[lo:lo + n]`` receives the
    triangles given a non-zero status other than an error, in order. ``counts[b]`` receives
    how many of them meet the rows of band ``b`` (``band_of[Y]`` is the band of sample row
    Y: a look-up, not two divisions, which are slower).

    Returns ``(lo, n, tris)``: ``tris`` lists, band after band, the kept triangles that meet
    each band's rows, each band's in triangle order (band ``b``'s are ``tris[s[b]:s[b] +
    counts[b]]``, ``s`` the running sum of ``counts``): this piece's band lists, made here
    while its boxes are in cache, so that no other pass, nor a wait for the other threads,
    comes between the cull and the raster (:func:`cull_and_bin`).
    """
    F, XY, w, huge, V, K = mesh
    r0, planes, perspective, FL, nW, nH, depth_ok, band_of = cull
    n = 0
    for b in range(counts.shape[0]):
        counts[b] = 0
    cand = np.empty(_BLOCK, np.uint32)        # unsigned: see _faces
    for b0 in range(lo, hi, _BLOCK):
        b1 = min(hi, b0 + _BLOCK)
        m = 0
        for t in range(b0, b1):
            status[t] = SKIP
            cand[m] = t
            m += 0 if depth_ok and _between_samples(K[F[t, 0]], K[F[t, 1]], K[F[t, 2]]) else 1
        for j in range(m):
            t = cand[j]
            i0 = F[t, 0]
            i1 = F[t, 1]
            i2 = F[t, 2]
            ax = XY[i0, 0]
            ay = XY[i0, 1]
            bx_ = XY[i1, 0]
            by_ = XY[i1, 1]
            cx = XY[i2, 0]
            cy = XY[i2, 1]
            xmin, xmax, ymin, ymax, X0, X1, Y0, Y1 = _sample_box(ax, ay, bx_, by_, cx, cy, nW,
                                                                 nH)
            if not depth_ok:
                w0 = w[i0]
                w1 = w[i1]
                w2 = w[i2]
                wmin = min(w0, min(w1, w2))
                wmax = max(w0, max(w1, w2))
                if wmax < 0.0 or wmin > FL:
                    continue  # behind the source or beyond the detector
                if perspective and wmax <= 0.0:
                    continue
                if wmin < 0.0 or (perspective and wmin <= 0.0):
                    if not beyond_side(V, i0, i1, i2, r0, planes):
                        status[t] = ERR_STRADDLE
                    continue
            if X0 > X1 or Y0 > Y1:
                continue  # covers no sample (outside the beam or between samples)
            if not depth_ok and (huge[i0] or huge[i1] or huge[i2]):
                status[t] = ERR_TOO_CLOSE
                continue
            small = max(xmax - xmin, ymax - ymin) < SAFE_EXTENT
            kind = SMALL if small else GIANT
            o = _orientation(bx_ - ax, by_ - ay, ax, ay, cx, cy, small)
            if o == 0:
                continue  # zero projected area: never hit
            status[t] = kind * o
            box[t, 0] = X0
            box[t, 1] = X1
            box[t, 2] = Y0
            box[t, 3] = Y1
            kept[lo + n] = t
            n += 1
            # The first band apart: the loop over the others (most triangles meet one band)
            # is then mostly empty, not a loop of one to mispredict at its end.
            bf = band_of[Y0]
            counts[bf] += 1
            for b in range(bf + 1, band_of[Y1] + 1):
                counts[b] += 1
    # The band lists: each kept triangle written to every band its rows meet (the first band
    # apart, as above; indices read from memory unsigned: no negative-index fix-up).
    nbands = counts.shape[0]
    off = np.empty(nbands, np.int64)
    total = np.int64(0)
    for b in range(nbands):
        off[b] = total
        total += counts[b]
    tris = np.empty(total, np.uint32)
    for m in range(lo, lo + n):
        t = kept[m]
        bf = band_of[np.uint64(box[t, 2])]
        tris[np.uint64(off[bf])] = t
        off[np.uint64(bf)] += 1
        for b in range(bf + 1, band_of[np.uint64(box[t, 3])] + 1):
            tris[np.uint64(off[b])] = t
            off[b] += 1
    return lo, n, tris


class Bands(NamedTuple):
    """The bands of sample rows :func:`_raster_bands` rasters, and each band's triangles
    (:func:`cull_and_bin`). A band is ``height`` whole rows of the fine grid."""

    #: ``(k,) int64``: the bands to raster, in the order the threads take them (longest first).
    order: np.ndarray
    #: ``(pieces, n_bands + 1) int64``: band ``b``'s triangles of the cull's piece ``c`` are
    #: ``tris[start[c, b]:start[c, b + 1]]``; over the pieces in turn, triangle order.
    start: np.ndarray
    #: ``(m,) uint32``: triangle indices (into :class:`Triangles`), listed by band.
    tris: np.ndarray
    #: Sample rows per band.
    height: int
    #: Sample rows of the fine grid (``n H``).
    nH: int
    #: Sample columns of the fine grid (``n W``).
    nW: int


class Triangles(NamedTuple):
    """The bodies' triangles as the cull left them (:func:`_cull_triangles`,
    :func:`project_vertices`); ``T`` triangles over ``n`` vertices."""

    #: ``(T,) int8``: SKIP, +-SMALL or +-GIANT (times the orientation: + enters a body).
    status: np.ndarray
    #: ``(T, 4) int64``: the sample box ``X0, X1, Y0, Y1`` (inclusive) each covers.
    box: np.ndarray
    #: ``(T, 3) uint32``: vertex indices (:func:`_faces`).
    F: np.ndarray
    #: ``(n, 2) int64``: the vertices projected and snapped (fixed point, ``ONE`` a step).
    XY: np.ndarray
    #: ``(3, n) float64``: the vertices, coordinate-major (:func:`_vertices`).
    V: np.ndarray
    #: ``(n,) float64``: each vertex's depth (mm along the frame's forward axis).
    w: np.ndarray
    #: ``(T,) int32``: the body of each triangle.
    body: np.ndarray


class Grid(NamedTuple):
    """The detector's fine grid in space: where sample (X, Y) is (``P00 + X Ex + Y Ey``) and
    how deep the detector is."""

    #: Depth of the detector (mm along the frame's forward axis): hits beyond it are dropped.
    FL: float
    #: A point source (True) or a parallel beam.
    perspective: bool
    #: ``(3,) float64``: sample (0, 0) on the detector.
    P00: np.ndarray
    #: ``(3,) float64``: one fine-grid step along X (``HO`` / (n W)).
    Ex: np.ndarray
    #: ``(3,) float64``: one fine-grid step along Y (``VE`` / (n H)).
    Ey: np.ndarray


class Frame(NamedTuple):
    """Where the rays come from and go: the source and the detector's grid (:func:`_plane`)."""

    #: ``(3,) float64``: the source (a point source) or a point on the beam (parallel).
    origin: np.ndarray
    #: ``(3,) float64``: a parallel beam's direction (unused for a point source).
    f: np.ndarray
    #: The detector's fine grid.
    grid: Grid


class Projected(NamedTuple):
    """One mesh's vertices projected and snapped by :func:`_project_vertices`; ``T``
    triangles over ``n`` vertices."""

    #: ``(T, 3) uint32``: vertex indices (:func:`_faces`).
    F: np.ndarray
    #: ``(n, 2) int64``: the vertices projected and snapped (fixed point, ``ONE`` a step).
    XY: np.ndarray
    #: ``(n,) float64``: each vertex's depth (mm along the frame's forward axis).
    w: np.ndarray
    #: ``(n,) bool``: a vertex too far out to be snapped.
    huge: np.ndarray
    #: ``(3, n) float64``: the vertices, coordinate-major (:func:`_vertices`).
    V: np.ndarray
    #: ``(n,) int32``: each vertex's cell code (:func:`_axis_code`).
    K: np.ndarray


class Projection(NamedTuple):
    """How :func:`_project_vertices` maps a vertex to the fine grid: ``rel = v - origin``,
    depth ``w = rel.f``, ``x = sx * (rel.eu) [/ w] + bx``, ``y = sy * (rel.ev) [/ w] + by``
    (``/ w`` for a point source)."""

    #: ``(3,) float64``: the source (a point source) or a point on the beam (parallel).
    origin: np.ndarray
    #: ``(3,) float64``: the depth axis (the frame's forward axis).
    f: np.ndarray
    #: ``(3,) float64``: the detector's across axis.
    eu: np.ndarray
    #: ``(3,) float64``: the detector's down axis.
    ev: np.ndarray
    #: Fine-grid steps per unit along ``eu`` (times the depth of the detector for a point source).
    sx: float
    #: Fine-grid x of the axis.
    bx: float
    #: Fine-grid steps per unit along ``ev``.
    sy: float
    #: Fine-grid y of the axis.
    by: float
    #: A point source (True) or a parallel beam.
    perspective: bool
    #: Sample columns of the fine grid (``n W``).
    nW: int
    #: Sample rows of the fine grid (``n H``).
    nH: int


class Cull(NamedTuple):
    """What :func:`_cull_triangles` tests the triangles against: the beam, the grid and the
    bands."""

    #: ``(3,) float64``: the source (a point source) or a point on the beam (parallel).
    origin: np.ndarray
    #: ``(k, 4) float64``: the beam's side planes (:func:`beyond_side`).
    planes: np.ndarray
    #: A point source (True) or a parallel beam.
    perspective: bool
    #: Depth of the detector (mm along the frame's forward axis).
    FL: float
    #: Sample columns of the fine grid (``n W``).
    nW: int
    #: Sample rows of the fine grid (``n H``).
    nH: int
    #: Every vertex strictly between the source and the detector planes, none huge: the
    #: first pass by cell codes (``Projected.K``) may drop triangles.
    depth_ok: bool
    #: ``(nH,) int64``: the band of each sample row.
    band_of: np.ndarray


class DepthSums(NamedTuple):
    """One body's output: per sample the signed depths and the crossings, for :func:`_finish`
    (the rows of the bands rastered, a window)."""

    #: ``(rows, nW) float64``: ``S[Y - row0, X] += sign * depth`` (exits +, entries -).
    S: np.ndarray
    #: ``(rows, nW) int32``: ``N[Y - row0, X] += 1`` per entry, ``-1`` per exit.
    N: np.ndarray
    #: The fine-grid row of ``S[0]`` and ``N[0]``.
    row0: int


class Rays(NamedTuple):
    """A window of the detector's rays in image order (:func:`_sample_ray`): their lengths."""

    #: ``(rays, bodies) float64``: lengths (mm) of the rays ``ray0 ..`` of the window.
    L: np.ndarray
    #: The first ray of ``L``.
    ray0: int
    #: Sub-rays per pixel side.
    n: int
    #: Detector pixels across.
    W: int
    #: Detector pixels down.
    H: int


class Sweep(NamedTuple):
    """Several bodies' output: each ray's length in the body of highest precedence
    (:func:`body_ranks`)."""

    #: ``(bodies,) int64``: each body's precedence rank (0 wins; -1 never wins).
    rank: np.ndarray
    #: ``(ranks,) int64``: the body of each rank.
    by_rank: np.ndarray
    #: The rays written.
    rays: Rays


@intrinsic
def _claim(typingctx, counter):
    """``counter[0]``, then ``counter[0] += 1``, atomically (one ``lock xadd``): the threads
    rastering bands take the next band each from one shared counter (numba has no atomics of
    its own; this is LLVM's ``atomicrmw add``)."""
    if not (isinstance(counter, numba.types.Array) and counter.dtype == numba.types.int64):
        return None
    sig = numba.types.int64(counter)

    def codegen(context, builder, signature, args):
        from llvmlite import ir

        ary = context.make_array(signature.args[0])(context, builder, args[0])
        return builder.atomic_rmw("add", ary.data, ir.Constant(ir.IntType(64), 1), "monotonic")
    return sig, codegen


@njit(cache=True, nogil=True, error_model="numpy")
def _raster_bands(lo, hi, bands, tris, frame, single, sums, sweep, claim):
    """The banded raster, one body (``single``: into ``sums``) or several (into ``sweep``):
    bands ``bands.order[k]``, ``lo <= k < hi`` (:class:`Bands`, :class:`Triangles`,
    :class:`Frame`, :class:`DepthSums`, :class:`Sweep`; the output not written is a
    dummy), each taken in turn (``k = lo + claim[0]``, the counter advanced atomically:
    :func:`_claim`) by every thread rastering these bands with the same ``claim``, which
    starts at 0: a thread that starts late or runs slow takes fewer bands, none waits for
    another at the end (with ``order`` longest first, a greedy list schedule).

    Each band's triangles (``band_tris[band_start[c, b]:band_start[c, b + 1]]`` over the
    cull's pieces ``c`` in turn, which is triangle order: :func:`cull_and_bin`; indices of
    the triangles of :func:`_cull_triangles`' ``status`` and ``box``) visit the samples of
    their rows that they cover (exact edge functions and the tie rule, int64 for SMALL
    triangles, limbs for GIANT ones; a SMALL triangle's box of at most 4 x 4 samples in one
    branch-free mask, wider ones row by row); a hit's depth is that of the triangle's plane
    (:func:`_plane`, from the vertices ``V``, the source ``origin`` and a parallel beam's
    direction ``f``) clamped to the range of its vertices' depths ``w``; a hit beyond the
    detector (depth > FL) is dropped. The plane is computed where the triangle is rastered,
    once per band it meets (1.1 times per triangle for the frog): that costs the raster no
    more than reading it from a set-up pass did. Several bodies: the band's hits are stored
    in triangle order; a triangle covers a sample once, so the order of its own hits (mask or
    rows) does not matter to the grouping below.

    ``single``: ``S[Y - row0, X] += sign * depth`` and ``N[Y - row0, X] += entering`` (so
    ``S`` and ``N`` need only hold the rows of the bands rastered, a window).

    Several bodies: the band's hits are stored in triangle order, grouped by sample (a stable
    counting sort), sorted by depth per sample (a stable insertion sort: few hits each) and
    swept: ``L[ray - ray0, b]`` receives the length (mm) of the ray of sample (X, Y) whose
    material is body ``b``, the body of highest precedence among those the ray is inside
    (entries minus exits > 0), up to the detector (depth FL): the body of lowest ``rank``
    (``by_rank[r]`` is the body of rank r; rank -1 never wins; :func:`body_ranks`). Rays are
    in image order (see :func:`finish`), so ``L`` need only hold the rays of the bands
    rastered; each band's rays are zeroed before its lengths are added (``L`` need not arrive
    zeroed). A sample's hits and their order do not depend on which bands are rastered
    together, nor on which thread rasters a band.
    """
    order, band_start, band_tris, band_height, nH, nW = bands
    status, box, F, XY, V, w, tri_body = tris
    origin, f, grid = frame
    FL, perspective, P00, Ex, Ey = grid
    S, N, row0 = sums
    rank, by_rank, rays = sweep
    L, ray0, n, W, H = rays
    nb = rank.shape[0]
    few = by_rank.shape[0] <= 65           # ranks fit the bits of a uint64
    p0, p1, p2 = P00[0], P00[1], P00[2]
    ex0, ex1, ex2 = Ex[0], Ex[1], Ex[2]
    ey0, ey1, ey2 = Ey[0], Ey[1], Ey[2]
    r0x, r0y, r0z = origin[0], origin[1], origin[2]
    f0, f1, f2 = f[0], f[1], f[2]
    sight = (perspective, r0x, r0y, r0z, p0, p1, p2, ex0, ex1, ex2, ey0, ey1, ey2, f0, f1, f2,
             FL)
    npix_max = band_height * nW
    pieces = band_start.shape[0]
    cap = 1024
    # Unsigned, as the faces (:func:`_faces`): indices without numba's negative-index fix-up.
    hk = np.empty(cap, np.uint32)         # sample of each hit (index in the band)
    hw = np.empty(cap, np.float64)        # its depth
    hb = np.empty(cap, np.uint32)         # body * 2 + entering
    cnt = np.zeros(npix_max + 1, np.int64)
    inside = np.zeros(max(nb, 1), np.int64)
    while True:
        k = lo + _claim(claim)
        if k >= hi:
            break
        b = order[k]
        r0 = b * band_height
        r1 = min(nH, r0 + band_height) - 1
        npix = (r1 - r0 + 1) * nW
        # Room for every sample of the band's boxes (one triangle's with ``single``), made
        # before the band: numba keeps buffers grown inside the triangle loop live through it.
        need = np.int64(0)
        for c in range(pieces):
            for idx in range(band_start[c, b], band_start[c, b + 1]):
                t = band_tris[idx]
                area = ((box[t, 1] - box[t, 0] + 1)
                        * (min(box[t, 3], r1) - max(box[t, 2], r0) + 1))
                need = max(need, area) if single else need + area
        if need > cap:
            cap = max(2 * cap, need)
            hk = np.empty(cap, np.uint32)
            hw = np.empty(cap, np.float64)
            hb = np.empty(cap, np.uint32)
        nh = np.int64(0)
        for c in range(pieces):
            for idx in range(band_start[c, b], band_start[c, b + 1]):
                t = band_tris[idx]
                y0 = max(box[t, 2], r0)
                y1 = min(box[t, 3], r1)
                X0 = box[t, 0]
                X1 = box[t, 1]
                n0 = nh
                st = status[t]
                code = np.int64(tri_body[t]) * 2 + (1 if st > 0 else 0)
                i0 = F[t, 0]
                i1 = F[t, 1]
                i2 = F[t, 2]
                # The triangle's hits in rows y0..y1, columns X0..X1, appended to hk (sample index
                # in the band), hw (depth), hb (code), samples in row then column order. Written
                # out here: numba does not inline a function of this size, and its call (the
                # arrays and some 25 numbers pushed per triangle entry) costs as much as a small
                # triangle's coverage.
                ax = XY[i0, 0]
                ay = XY[i0, 1]
                bx = XY[i1, 0]
                by = XY[i1, 1]
                cx = XY[i2, 0]
                cy = XY[i2, 1]
                o = np.int64(1 if st > 0 else -1)
                small = abs(st) == SMALL
                c0, c1, c2, c3, c4, c5 = _plane(
                    (V[0, i0], V[1, i0], V[2, i0]), (V[0, i1], V[1, i1], V[2, i1]),
                    (V[0, i2], V[1, i2], V[2, i2]), sight)
                w0 = w[i0]
                w1 = w[i1]
                w2 = w[i2]
                wmin = min(w0, min(w1, w2))
                wmax = max(w0, max(w1, w2))
                # Edges a->b, b->c, c->a: E = ex * (py - sy) - ey * (px - sx), times o (inside:
                # E > 0).
                e0x, e0y, e1x, e1y, e2x, e2y = _edges(ax, ay, bx, by, cx, cy)
                # Exact edge functions and the tie rule: int64 for SMALL triangles, limbs for
                # GIANT ones; a hit beyond the detector (depth > FL) is dropped.
                bias0, bias1, bias2 = _tie_biases(o, e0x, e0y, e1x, e1y, e2x, e2y)
                if small and X1 - X0 <= 3 and y1 - y0 <= 3:
                    # A box of at most 4 x 4 samples (most of a fine mesh's): its covered
                    # samples as the bits of a mask, the edge functions at all 16 places
                    # and the tie rule without a branch, then each covered sample's depth
                    # (the same hits, in the same order, as the rows below).
                    px = X0 * ONE
                    py = y0 * ONE
                    E0 = o * _edge_function(e0x, e0y, px - ax, py - ay)
                    E1 = o * _edge_function(e1x, e1y, px - bx, py - by)
                    E2 = o * _edge_function(e2x, e2y, px - cx, py - cy)
                    sx0 = -o * e0y * ONE
                    sx1 = -o * e1y * ONE
                    sx2 = -o * e2y * ONE
                    sy0 = o * e0x * ONE
                    sy1 = o * e1x * ONE
                    sy2 = o * e2x * ONE
                    wx = X1 - X0
                    wy = y1 - y0
                    cover = np.int64(0)
                    for q in range(16):
                        dx = q & 3
                        dy = q >> 2
                        inq = ((E0 + dx * sx0 + dy * sy0 >= bias0)
                               & (E1 + dx * sx1 + dy * sy1 >= bias1)
                               & (E2 + dx * sx2 + dy * sy2 >= bias2) & (dx <= wx) & (dy <= wy))
                        cover |= np.int64(inq) << q
                    while cover:
                        q = _lowest_bit(np.uint64(cover))
                        cover &= cover - 1
                        X = X0 + (q & 3)
                        Y = y0 + (q >> 2)
                        Wd = _clamped(c0, c1, c2, c3, c4, c5, X, Y, wmin, wmax)
                        hk[np.uint64(nh)] = (Y - r0) * nW + X
                        hw[np.uint64(nh)] = Wd
                        hb[np.uint64(nh)] = code
                        nh += np.int64(Wd <= FL)
                elif small:
                    px0 = X0 * ONE
                    stepx0 = -o * e0y * ONE
                    stepx1 = -o * e1y * ONE
                    stepx2 = -o * e2y * ONE
                    for Y in range(y0, y1 + 1):
                        py = Y * ONE
                        E0 = o * _edge_function(e0x, e0y, px0 - ax, py - ay)
                        E1 = o * _edge_function(e1x, e1y, px0 - bx, py - by)
                        E2 = o * _edge_function(e2x, e2y, px0 - cx, py - cy)
                        for X in range(X0, X1 + 1):
                            # Every sample of the row is stored and kept (nh moves on) when
                            # it is covered: no branch to mispredict at the triangle's edges.
                            # The room made for the band
                            # counts every sample of its boxes.
                            Wd = _clamped(c0, c1, c2, c3, c4, c5, X, Y, wmin, wmax)
                            hk[np.uint64(nh)] = (Y - r0) * nW + X
                            hw[np.uint64(nh)] = Wd
                            hb[np.uint64(nh)] = code
                            nh += np.int64((E0 >= bias0) & (E1 >= bias1) & (E2 >= bias2)
                                           & (Wd <= FL))
                            E0 += stepx0
                            E1 += stepx1
                            E2 += stepx2
                else:
                    for Y in range(y0, y1 + 1):
                        py = Y * ONE
                        for X in range(X0, X1 + 1):
                            if _inside_exact(o, X * ONE, py, (ax, ay, bx, by, cx, cy),
                                             (e0x, e0y, e1x, e1y, e2x, e2y),
                                             (bias0, bias1, bias2)):
                                Wd = _clamped(c0, c1, c2, c3, c4, c5, X, Y, wmin, wmax)
                                if Wd <= FL:
                                    hk[np.uint64(nh)] = (Y - r0) * nW + X
                                    hw[np.uint64(nh)] = Wd
                                    hb[np.uint64(nh)] = code
                                    nh += 1
                if single:
                    sgn = -1.0 if st > 0 else 1.0
                    dn = 1 if st > 0 else -1
                    for i in range(n0, nh):
                        Y = r0 + hk[i] // nW
                        X = hk[i] - (Y - r0) * nW
                        S[Y - row0, X] += sgn * hw[i]
                        N[Y - row0, X] += dn
                    nh = np.int64(0)
        if single:
            continue
        # The band's rays (whole pixel rows j0..j1, Y up; image rows down) start at zero:
        # ``L`` need not arrive zeroed (a reused buffer), and the rows are then in the cache.
        # A slice assignment (a memset), quicker than a loop over rays and bodies.
        j0 = r0 // n
        j1 = r1 // n
        L[(H - 1 - j1) * W * n * n - ray0:(H - j0) * W * n * n - ray0] = 0.0
        if nh == 0:
            continue
        # Group the hits by sample, keeping their order (counting sort).
        for p in range(npix + 1):
            cnt[p] = 0
        for i in range(nh):
            cnt[hk[i] + np.uint32(1)] += 1
        for p in range(npix):
            cnt[p + 1] += cnt[p]
        bw = np.empty(nh, np.float64)
        bb = np.empty(nh, np.uint32)
        for i in range(nh):
            j = cnt[hk[i]]
            cnt[hk[i]] = j + 1
            bw[np.uint64(j)] = hw[i]
            bb[np.uint64(j)] = hb[i]
        # cnt[p] is now the end of sample p's hits (the start of p + 1's).
        # Unsigned indices where they are read from memory or counted (``nh``, ``j``, ``i``
        # from ``cnt``): numba adds a negative-index fix-up to a signed one; the sample's X, Y
        # kept alongside p, not divided out of it.
        start = 0
        Xp = -1
        Yp = r0
        for p in range(npix):
            Xp += 1
            Yp = Yp + 1 if Xp == nW else Yp
            Xp = 0 if Xp == nW else Xp
            lo_ = start
            hi_ = cnt[p]
            start = hi_
            if hi_ == lo_:
                continue
            # Insertion sort of the sample's hits by depth (few per sample).
            for i in range(lo_ + 1, hi_):
                kw = bw[np.uint64(i)]
                kb = bb[np.uint64(i)]
                j = i - 1
                while j >= lo_ and bw[np.uint64(j)] > kw:
                    bw[np.uint64(j + 1)] = bw[np.uint64(j)]
                    bb[np.uint64(j + 1)] = bb[np.uint64(j)]
                    j -= 1
                bw[np.uint64(j + 1)] = kw
                bb[np.uint64(j + 1)] = kb
            Y = Yp
            X = Xp
            ray = _sample_ray(X, Y, W, H, n)
            scale = (_obliquity(X, Y, p0, p1, p2, ex0, ex1, ex2, ey0, ey1, ey2, FL)
                     if perspective else 1.0)
            # The winner (highest precedence among the bodies the ray is inside, the lowest
            # index among equals) is the lowest set bit of ``mask`` over the bodies' ranks.
            mask = np.uint64(0)
            for i in range(lo_, hi_):
                c = bb[np.uint64(i)]
                q = c >> np.uint32(1)
                if c & 1:
                    inside[q] += 1
                else:
                    inside[q] -= 1
                win = -1
                if few:
                    r = rank[q]
                    if r >= 0:
                        if inside[q] > 0:
                            mask |= np.uint64(1) << np.uint64(r)
                        else:
                            mask &= ~(np.uint64(1) << np.uint64(r))
                    if mask:
                        win = by_rank[_lowest_bit(mask)]
                else:                      # more than 64 ranked bodies: look at each
                    best = nb
                    for qq in range(nb):
                        if inside[qq] > 0 and 0 <= rank[qq] < best:
                            best = rank[qq]
                            win = qq
                if win >= 0:
                    nxt = bw[np.uint64(i + 1)] if i + 1 < hi_ else FL
                    seg = nxt - bw[np.uint64(i)]
                    if seg > 0.0:
                        L[np.uint64(ray - ray0), np.uint64(win)] += seg * scale
            for i in range(lo_, hi_):
                inside[bb[np.uint64(i)] >> np.uint32(1)] = 0


_DEBRUIJN = np.uint64(0x03F79D71B4CB0A89)
_DEBRUIJN_INDEX = np.array([0, 1, 48, 2, 57, 49, 28, 3, 61, 58, 50, 42, 38, 29, 17, 4, 62, 55,
                            59, 36, 53, 51, 43, 22, 45, 39, 33, 30, 24, 18, 12, 5, 63, 47, 56,
                            27, 60, 41, 37, 16, 54, 35, 52, 21, 44, 32, 23, 11, 46, 26, 40, 15,
                            34, 20, 31, 10, 25, 14, 19, 9, 13, 8, 7, 6], np.int64)


@njit(cache=True, nogil=True, error_model="numpy")
def _lowest_bit(x):
    """Index of the lowest set bit of a non-zero uint64 (de Bruijn multiplication)."""
    iso = x & (~x + np.uint64(1))
    return _DEBRUIJN_INDEX[(iso * _DEBRUIJN) >> np.uint64(58)]


@njit(cache=True, nogil=True, error_model="numpy")
def _finish(lo, hi, S, N, Lf, single, grid, rays, s_row0):
    """Fine grid -> rays in image order, depth units -> mm along each ray.

    One body (``single``): the depth span of sample (X, Y) is ``sum_c S[c, Y - s_row0, X]``
    over the per-thread accumulators (one when ``S`` is a sum already), plus
    ``sum_c N[c, ...] * FL`` when ``N`` has chunks (as :func:`_reduce_chunks`). Several
    bodies: ``Lf[Y - s_row0, X, q]``. Only the fine rows ``lo <= Y < hi`` are done (a window
    of whole pixel rows), into ``rays.L[ray - rays.ray0]`` (:class:`Rays`; the samples'
    places: :class:`Grid`): every ray of those rows is written (``L`` need not arrive
    zeroed).

    Sample (X, Y), ``X = n i + c``, ``Y = n j + (n - 1 - r)``, is ray
    ``((H - 1 - j) W + i) n n + r n + c`` (:func:`_sample_ray`, here kept incrementally). A
    point-source ray's length is its depth span times ``|D| / FL`` (D from the source to the
    sample's detector point).
    """
    FL, perspective, P00, Ex, Ey = grid
    L, ray0, n, W, H = rays
    nb = L.shape[1]
    n_chunks = S.shape[0]
    counts = N.shape[0] != 0
    # The frame read once (numba cannot prove that L does not alias it).
    p0, p1, p2 = P00[0], P00[1], P00[2]
    ex0, ex1, ex2 = Ex[0], Ex[1], Ex[2]
    ey0, ey1, ey2 = Ey[0], Ey[1], Ey[2]
    if single and n == 1:
        # One body, no supersampling: a row of samples is a row of rays, done in loops that
        # LLVM vectorises (the same sums in the same order).
        Lr = L.reshape(L.shape[0])
        acc = np.empty(W)
        cnt = np.empty(W, np.int64)
        for Y in range(lo, hi):
            row = (H - 1 - Y) * W - ray0
            y = Y - s_row0
            for X in range(W):
                acc[X] = 0.0
                cnt[X] = 0
            for q in range(n_chunks):
                Sq = S[q, y]
                for X in range(W):
                    acc[X] += Sq[X]
            if counts:
                for q in range(n_chunks):
                    Nq = N[q, y]
                    for X in range(W):
                        cnt[X] += Nq[X]
            for X in range(W):
                v = acc[X] + cnt[X] * FL if counts else acc[X]
                scale = (_obliquity(X, Y, p0, p1, p2, ex0, ex1, ex2, ey0, ey1, ey2, FL)
                         if perspective else 1.0)
                Lr[row + X] = v * scale          # (v is never -0.0: sums start at 0.0)
        return
    for Y in range(lo, hi):
        j = Y // n
        row = ((H - 1 - j) * W * n + (n - 1 - (Y - j * n))) * n - ray0
        y = Y - s_row0
        for i in range(W):
            for c in range(n):
                X = n * i + c
                if single:
                    v = 0.0
                    k = 0
                    for q in range(n_chunks):
                        v += S[q, y, X]
                        k += N[q, y, X] if counts else 0
                    v = v + k * FL if counts else v
                ray = row + i * n * n + c
                if single and v == 0.0:
                    L[ray, 0] = 0.0
                    continue
                scale = (_obliquity(X, Y, p0, p1, p2, ex0, ex1, ex2, ey0, ey1, ey2, FL)
                         if perspective else 1.0)
                if single:
                    L[ray, 0] = v * scale
                else:
                    for q in range(nb):
                        L[ray, q] = Lf[y, X, q] * scale


@njit(cache=True, nogil=True, error_model="numpy")
def _sample_ray(X, Y, W, H, n):
    """The image-order ray of fine sample (X, Y) of an ``n x n`` supersampled W x H grid:
    with ``X = n i + c`` and ``Y = n j + (n - 1 - r)`` (Y up, image rows down), ray
    ``((H - 1 - j) W + i) n n + r n + c`` of :func:`xray_viz.geometry.detector_rays`. The one
    place of this index in the kernels."""
    if n == 1:                        # no supersampling: no divisions
        return (H - 1 - Y) * W + X
    j = Y // n
    i = X // n
    return ((H - 1 - j) * W + i) * n * n + (n - 1 - (Y - j * n)) * n + (X - i * n)


@njit(cache=True, nogil=True, error_model="numpy")
def _obliquity(X, Y, p0, p1, p2, ex0, ex1, ex2, ey0, ey1, ey2, FL):
    """``|D| / FL`` of fine sample (X, Y), D = P00 + X Ex + Y Ey from a point source to the
    sample's detector point (the frame's vectors as scalars, read once by the caller): a depth
    span along the beam axis times this is the length along the ray. The one place of this
    scale in the kernels."""
    dx = p0 + X * ex0 + Y * ey0
    dy = p1 + X * ex1 + Y * ey1
    dz = p2 + X * ex2 + Y * ey2
    return np.sqrt(dx * dx + dy * dy + dz * dz) / FL


@njit(cache=True, nogil=True, error_model="numpy")
def _plane(a, b, c, sight):
    """Coefficients of the depth ``(c0 + c1 X + c2 Y) / (c3 + c4 X + c5 Y)`` of the hit of the
    ray of sample (X, Y) with the plane of the triangle of vertices a, b, c (each ``(x, y,
    z)``; see :func:`_raster_bands`). ``sight`` is the frame as scalars, read once by the
    caller: ``(perspective, r0x, r0y, r0z, p0, p1, p2, ex0, ex1, ex2, ey0, ey1, ey2, f0, f1,
    f2, FL)`` (the source r0, P00, Ex, Ey, a parallel beam's f, the detector's depth).

    Point source: ray r0 + s D, D = P00 + X Ex + Y Ey (P00 relative to r0), hit depth s * FL.
    Parallel beam: ray O + t f, O = r0 + P00 + X Ex + Y Ey (P00 relative to the detector centre).

    Scalars only (in tuples), so that LLVM inlines it: a compiled helper taking arrays is
    called, not inlined, and pushing every array's fields costs several times this arithmetic.
    """
    ax, ay, az = a
    bx, by, bz = b
    cx, cy, cz = c
    (perspective, r0x, r0y, r0z, p0, p1, p2, ex0, ex1, ex2, ey0, ey1, ey2, f0, f1, f2,
     FL) = sight
    f1x = bx - ax
    f1y = by - ay
    f1z = bz - az
    f2x = cx - ax
    f2y = cy - ay
    f2z = cz - az
    nx = f1y * f2z - f1z * f2y
    ny = f1z * f2x - f1x * f2z
    nz = f1x * f2y - f1y * f2x
    qx = ax - r0x
    qy = ay - r0y
    qz = az - r0z
    nEx = nx * ex0 + ny * ex1 + nz * ex2
    nEy = nx * ey0 + ny * ey1 + nz * ey2
    if perspective:
        return (FL * (nx * qx + ny * qy + nz * qz), 0.0, 0.0, nx * p0 + ny * p1 + nz * p2,
                nEx, nEy)
    return (nx * (qx - p0) + ny * (qy - p1) + nz * (qz - p2), -nEx, -nEy,
            nx * f0 + ny * f1 + nz * f2, 0.0, 0.0)


@njit(cache=True, nogil=True, error_model="numpy")
def _clamped(c0, c1, c2, c3, c4, c5, X, Y, wmin, wmax):
    """The depth ``(c0 + c1 X + c2 Y) / (c3 + c4 X + c5 Y)`` of :func:`_plane`'s coefficients
    at sample (X, Y), clamped to ``[wmin, wmax]`` (the middle of the range when it is NaN).
    Selects, no branch: a caller may evaluate it at samples it then drops without a branch
    of its own to mispredict (the banded raster's rows)."""
    Wd = (c0 + c1 * X + c2 * Y) / (c3 + c4 * X + c5 * Y)
    Wd = 0.5 * (wmin + wmax) if Wd != Wd else Wd
    Wd = wmin if Wd < wmin else Wd
    return wmax if Wd > wmax else Wd


_BLOCK = 1024


@njit(cache=True, nogil=True, error_model="numpy")
def _raster_direct(lo, hi, n_chunks, mesh, frame, nW, nH, depth_ok, planes, S, err):
    """One body, in one sweep over the triangles: cull, cover, depth and accumulate.

    Triangles are split into ``n_chunks`` contiguous chunks; chunk ``c`` accumulates into its
    own ``S[c]`` (no races; zeroed by the caller), summed by the caller: a sample's depths of
    its hits, minus where the surface enters the body (seen from the source), plus where it
    leaves, which is its depth span. No vertex may lie beyond the detector plane (depth
    ``FL``): the caller sends such a body to the banded raster, which counts the crossings
    it drops there. ``err[c]`` receives the index of a triangle that cannot be projected
    (straddling or too close to the source plane), else -1; a straddling triangle wholly
    outside one of the beam's side ``planes`` is skipped instead.

    By blocks of ``_BLOCK`` triangles. When ``depth_ok``, a branch-free first pass drops the
    triangles whose three vertices share an even cell code on an axis (``K``, see
    :func:`project_vertices`: strictly between two sample columns or rows, or off the grid);
    the codes are gathered into columns and tested in a loop that LLVM vectorises.

    Then, when ``depth_ok`` and the previous block decided at least half of its triangles so
    (re-tried every 16th block), the triangles whose sample box holds a single sample (most
    triangles of a fine mesh) are decided in a vectorised loop, their snapped vertices
    gathered into columns first: the three edge functions at the sample (inside when none is
    zero and all have one sign, which is then the orientation). Every other triangle takes
    the general path below (tie rules, exact limb arithmetic for large ones, the depth checks
    when not ``depth_ok``). The last pass visits the block's hits (their depth: plane and
    clamp) and its general triangles in triangle order, so that every sample's sum is added
    in the order of one scalar loop: the same bits.

    Indices read from memory (``F``'s vertex numbers, the block's lists) or counted are
    unsigned (or made so where they index): numba then indexes without the fix-up of negative
    indices that it adds for signed ones (a compare and select each, which slows the gathers
    of the cell codes most; ``benchmarks/notes/kernels.md``).
    """
    F, XY, w, huge, V, K = mesh
    r0, f, grid = frame
    FL, perspective, P00, Ex, Ey = grid
    T = F.shape[0]
    per = (T + n_chunks - 1) // n_chunks
    r0x, r0y, r0z = r0[0], r0[1], r0[2]
    p0, p1, p2 = P00[0], P00[1], P00[2]
    ex0, ex1, ex2 = Ex[0], Ex[1], Ex[2]
    ey0, ey1, ey2 = Ey[0], Ey[1], Ey[2]
    f0, f1, f2 = f[0], f[1], f[2]
    sight = (perspective, r0x, r0y, r0z, p0, p1, p2, ex0, ex1, ex2, ey0, ey1, ey2, f0, f1, f2,
             FL)
    for c in range(lo, hi):
        err[c] = -1
        Sc = S[c]
        cand = np.empty(_BLOCK, np.uint32)
        Ka = np.empty(_BLOCK, np.int32)
        Kb = np.empty(_BLOCK, np.int32)
        Kc = np.empty(_BLOCK, np.int32)
        keep = np.empty(_BLOCK, np.int64)
        # Columns of the block's one-sample work: arrays of their own, contiguous (as views of
        # the rows of one 2-D array they are not known to be, and the loops stay scalar).
        Pax = np.empty(_BLOCK, np.int64)
        Pay = np.empty(_BLOCK, np.int64)
        Pbx = np.empty(_BLOCK, np.int64)
        Pby = np.empty(_BLOCK, np.int64)
        Pcx = np.empty(_BLOCK, np.int64)
        Pcy = np.empty(_BLOCK, np.int64)
        kind = np.empty(_BLOCK, np.int64)
        sample_x = np.empty(_BLOCK, np.uint32)
        sample_y = np.empty(_BLOCK, np.uint32)
        hits = np.empty(_BLOCK, np.uint32)
        general = np.empty(_BLOCK, np.uint32)
        hi = min(T, (c + 1) * per)
        mostly_one = True
        for b0 in range(c * per, hi, _BLOCK):
            # Pass 1 (branch free): drop the triangles whose three vertices share an even cell
            # code on an axis (strictly between two sample columns or rows: no sample covered);
            # the codes gathered into columns, the test vectorised, then the list.
            nb = min(hi, b0 + _BLOCK) - b0
            Fb = F[b0:b0 + nb]
            for j in range(nb):
                Ka[j] = K[Fb[j, 0]]
                Kb[j] = K[Fb[j, 1]]
                Kc[j] = K[Fb[j, 2]]
            for j in range(nb):
                keep[j] = 0 if _between_samples(Ka[j], Kb[j], Kc[j]) & depth_ok else 1
            m = 0
            for j in range(nb):
                cand[np.uint64(m)] = b0 + j
                m += keep[j]
            # Pass 2, on the first mm candidates (all or none): one-sample triangles decided,
            # kind +-1 a hit (the sign is the orientation), 0 missed, +-2 the general path.
            mm = m if (depth_ok and (mostly_one or (b0 // _BLOCK) % 16 == 0)) else 0
            for j in range(mm):
                t = cand[j]
                i0 = F[t, 0]
                i1 = F[t, 1]
                i2 = F[t, 2]
                Pax[j] = XY[i0, 0]
                Pay[j] = XY[i0, 1]
                Pbx[j] = XY[i1, 0]
                Pby[j] = XY[i1, 1]
                Pcx[j] = XY[i2, 0]
                Pcy[j] = XY[i2, 1]
            for j in range(mm):
                ax = Pax[j]
                ay = Pay[j]
                bx = Pbx[j]
                by = Pby[j]
                cx = Pcx[j]
                cy = Pcy[j]
                xmin, xmax, ymin, ymax, X0, X1, Y0, Y1 = _sample_box(ax, ay, bx, by, cx, cy, nW,
                                                                     nH)
                one = (X0 == X1) & (Y0 == Y1) & (max(xmax - xmin, ymax - ymin) < SAFE_EXTENT)
                # E_k = e_k x (p - start of edge k) at p = (X0, Y0); the inputs are zeroed
                # unless the box is small, so that no product can overflow. Every factor is
                # then below 2**30 in magnitude (p lies in the box): through int32
                # (:func:`_i32`), LLVM multiplies 32 x 32 -> 64 bits (vpmuldq, one uop,
                # against three of a 64-bit vpmullq).
                px = X0 * ONE
                py = Y0 * ONE
                E0 = _edge_function(_i32((bx - ax) if one else 0), _i32((by - ay) if one else 0),
                                    _i32((px - ax) if one else 0), _i32((py - ay) if one else 0))
                E1 = _edge_function(_i32((cx - bx) if one else 0), _i32((cy - by) if one else 0),
                                    _i32((px - bx) if one else 0), _i32((py - by) if one else 0))
                E2 = _edge_function(_i32((ax - cx) if one else 0), _i32((ay - cy) if one else 0),
                                    _i32((px - cx) if one else 0), _i32((py - cy) if one else 0))
                # E0 + E1 + E2 is the projected area: all one sign -> inside, and that sign is
                # the orientation; mixed signs -> outside (or zero area). A zero: general path.
                decided = one & (E0 != 0) & (E1 != 0) & (E2 != 0)
                inside = ((E0 > 0) & (E1 > 0) & (E2 > 0)) | ((E0 < 0) & (E1 < 0) & (E2 < 0))
                k = (np.int64(1) if inside else np.int64(0)) if decided else np.int64(2)
                k = np.int64(0) if (X0 > X1) | (Y0 > Y1) else k
                kind[j] = k if E0 > 0 else -k
                sample_x[j] = X0
                sample_y[j] = Y0
            h = 0
            ng = 0
            for j in range(mm):
                kj = kind[j]
                hits[np.uint64(h)] = j
                h += (kj == 1) | (kj == -1)
                general[np.uint64(ng)] = j
                ng += (kj == 2) | (kj == -2)
            if mm:
                mostly_one = 2 * (mm - ng) >= mm
            else:
                ng = m                          # every candidate: general[g] is g
            # Pass 3, in triangle order: the hits accumulated, the general path.
            q = 0
            g = 0
            while q < h or g < ng:
                if g < ng and (q >= h or general[np.uint64(g)] < hits[np.uint64(q)]):
                    t = cand[general[np.uint64(g)]] if mm else cand[np.uint64(g)]
                    g += 1
                else:
                    j = hits[np.uint64(q)]
                    q += 1
                    t = cand[j]
                    i0 = F[t, 0]
                    i1 = F[t, 1]
                    i2 = F[t, 2]
                    c0, c1, c2, c3, c4, c5 = _plane(
                        (V[0, i0], V[1, i0], V[2, i0]), (V[0, i1], V[1, i1], V[2, i1]),
                        (V[0, i2], V[1, i2], V[2, i2]), sight)
                    # (the sample as int64: _clamped has one specialisation)
                    Wd = _clamped(c0, c1, c2, c3, c4, c5, np.int64(sample_x[j]),
                                  np.int64(sample_y[j]), min(w[i0], min(w[i1], w[i2])),
                                  max(w[i0], max(w[i1], w[i2])))
                    if kind[j] > 0:
                        Sc[sample_y[j], sample_x[j]] -= Wd
                    else:
                        Sc[sample_y[j], sample_x[j]] += Wd
                    continue
                i0 = F[t, 0]
                i1 = F[t, 1]
                i2 = F[t, 2]
                ax = XY[i0, 0]
                ay = XY[i0, 1]
                bx = XY[i1, 0]
                by = XY[i1, 1]
                cx = XY[i2, 0]
                cy = XY[i2, 1]
                xmin, xmax, ymin, ymax, X0, X1, Y0, Y1 = _sample_box(ax, ay, bx, by, cx, cy, nW,
                                                                     nH)
                if depth_ok:
                    if X0 > X1 or Y0 > Y1:
                        continue
                    wmin = 0.0
                    wmax = 0.0
                else:
                    w0 = w[i0]
                    w1 = w[i1]
                    w2 = w[i2]
                    wmin = min(w0, min(w1, w2))
                    wmax = max(w0, max(w1, w2))
                    if wmax < 0.0 or wmin > FL:
                        continue
                    if perspective and wmax <= 0.0:
                        continue
                    if wmin < 0.0 or (perspective and wmin <= 0.0):
                        if not beyond_side(V, i0, i1, i2, r0, planes):
                            err[c] = t
                        continue
                    if X0 > X1 or Y0 > Y1:
                        continue
                    if huge[i0] or huge[i1] or huge[i2]:
                        err[c] = t
                        continue
                small = max(xmax - xmin, ymax - ymin) < SAFE_EXTENT
                e0x, e0y, e1x, e1y, e2x, e2y = _edges(ax, ay, bx, by, cx, cy)
                if small and X0 == X1 and Y0 == Y1:
                    # One sample: E_k = e_k x (p - start of edge k) at p = (X0, Y0). Apart
                    # from the rows below (which give it the same bits) because it needs no
                    # orientation or tie rule, and the scalar path (depth_ok False) is slower
                    # through the rows.
                    px = X0 * ONE
                    py = Y0 * ONE
                    E0 = _edge_function(e0x, e0y, px - ax, py - ay)
                    E1 = _edge_function(e1x, e1y, px - bx, py - by)
                    E2 = _edge_function(e2x, e2y, px - cx, py - cy)
                    if E0 != 0 and E1 != 0 and E2 != 0:
                        # E0 + E1 + E2 is the projected area: all one sign -> inside, and that
                        # sign is the orientation; mixed signs -> outside (or zero area).
                        if E0 > 0:
                            if E1 < 0 or E2 < 0:
                                continue
                            sgn = -1.0
                        else:
                            if E1 > 0 or E2 > 0:
                                continue
                            sgn = 1.0
                        if depth_ok:
                            wmin = min(w[i0], min(w[i1], w[i2]))
                            wmax = max(w[i0], max(w[i1], w[i2]))
                        c0, c1, c2, c3, c4, c5 = _plane(
                            (V[0, i0], V[1, i0], V[2, i0]), (V[0, i1], V[1, i1], V[2, i1]),
                            (V[0, i2], V[1, i2], V[2, i2]), sight)
                        Wd = _clamped(c0, c1, c2, c3, c4, c5, X0, Y0, wmin, wmax)
                        Sc[np.uint64(Y0), np.uint64(X0)] += sgn * Wd
                        continue
                o = _orientation(e0x, e0y, ax, ay, cx, cy, small)
                if o == 0:
                    continue
                sgn = -1.0 if o > 0 else 1.0            # entering: minus its depth
                bias0, bias1, bias2 = _tie_biases(o, e0x, e0y, e1x, e1y, e2x, e2y)
                if small:
                    # Every sample of the box: its depth, then added (or 0 added) by whether
                    # it is covered, without a branch to mispredict at the triangle's edges.
                    # Adding 0.0 to a sum
                    # that starts at +0.0 leaves its bits as they are.
                    if depth_ok:
                        wmin = min(w[i0], min(w[i1], w[i2]))
                        wmax = max(w[i0], max(w[i1], w[i2]))
                    c0, c1, c2, c3, c4, c5 = _plane(
                        (V[0, i0], V[1, i0], V[2, i0]), (V[0, i1], V[1, i1], V[2, i1]),
                        (V[0, i2], V[1, i2], V[2, i2]), sight)
                    for Y in range(Y0, Y1 + 1):
                        py = Y * ONE
                        E0 = o * _edge_function(e0x, e0y, X0 * ONE - ax, py - ay)
                        E1 = o * _edge_function(e1x, e1y, X0 * ONE - bx, py - by)
                        E2 = o * _edge_function(e2x, e2y, X0 * ONE - cx, py - cy)
                        for X in range(X0, X1 + 1):
                            Wd = _clamped(c0, c1, c2, c3, c4, c5, X, Y, wmin, wmax)
                            kept = (E0 >= bias0) & (E1 >= bias1) & (E2 >= bias2)
                            Sc[np.uint64(Y), np.uint64(X)] += sgn * Wd if kept else 0.0
                            E0 -= o * e0y * ONE
                            E1 -= o * e1y * ONE
                            E2 -= o * e2y * ONE
                    continue
                # A GIANT triangle: exact signs, its plane once a sample is covered.
                have_plane = False
                c0 = 0.0
                c1 = 0.0
                c2 = 0.0
                c3 = 0.0
                c4 = 0.0
                c5 = 0.0
                for Y in range(Y0, Y1 + 1):
                    py = Y * ONE
                    for X in range(X0, X1 + 1):
                        if not _inside_exact(o, X * ONE, py, (ax, ay, bx, by, cx, cy),
                                             (e0x, e0y, e1x, e1y, e2x, e2y),
                                             (bias0, bias1, bias2)):
                            continue
                        if not have_plane:
                            have_plane = True
                            if depth_ok:
                                wmin = min(w[i0], min(w[i1], w[i2]))
                                wmax = max(w[i0], max(w[i1], w[i2]))
                            c0, c1, c2, c3, c4, c5 = _plane(
                                (V[0, i0], V[1, i0], V[2, i0]), (V[0, i1], V[1, i1], V[2, i1]),
                                (V[0, i2], V[1, i2], V[2, i2]), sight)
                        Wd = _clamped(c0, c1, c2, c3, c4, c5, X, Y, wmin, wmax)
                        Sc[Y, X] += sgn * Wd


@njit(cache=True, nogil=True, error_model="numpy")
def _reduce_chunks(lo, hi, S, N, FL, out):
    """``out = sum_c S[c] + N[c] * FL`` (depth span of each sample, one body); ``sum_c S[c]``
    when ``N`` has no chunks (:func:`_raster_direct`'s sums need no counts)."""
    n_chunks, nH, nW = S.shape
    counts = N.shape[0] != 0
    for Y in range(lo, hi):
        for X in range(nW):
            s = 0.0
            k = 0
            for c in range(n_chunks):
                s += S[c, Y, X]
                k += N[c, Y, X] if counts else 0
            out[Y, X] = s + k * FL if counts else s


# --------------------------------------------------------------------------------------------
# Explicit signatures.
#
# Each kernel above has exactly one specialisation, ``SIGNATURES[name]``: :data:`KERNELS`
# compiles it (or loads it from numba's cache) the first time the engine needs it, then the
# dispatcher compiles nothing else, so no argument type can cost another compilation
# (:mod:`xray_viz.tracing._compile`). :mod:`xray_viz.tracing._raster_calls` normalises the
# arguments to those types and splits each kernel's range over the library's threads.

from numba.core import types as _nt  # noqa: E402

from xray_viz.tracing._compile import KernelSet  # noqa: E402

_SCALARS = {"i8": _nt.int64, "f8": _nt.float64, "b1": _nt.boolean}
_DTYPES = {"i8": _nt.int64, "i4": _nt.int32, "u4": _nt.uint32, "i1": _nt.int8,
           "f8": _nt.float64, "b1": _nt.boolean}


#: Field types of the named tuples the kernels take (see :func:`_types`).
TUPLES = {
    "Bands": (Bands, "i8[1]r i8[2]r u4[1]r i8 i8 i8"),
    "Triangles": (Triangles, "i1[1]r i8[2]r u4[2]r i8[2]r f8[2]r f8[1]r i4[1]r"),
    "Grid": (Grid, "f8 b1 f8[1]r f8[1]r f8[1]r"),
    "Frame": (Frame, "f8[1]r f8[1]r Grid"),
    "Projected": (Projected, "u4[2]r i8[2]r f8[1]r b1[1]r f8[2]r i4[1]r"),
    "Projection": (Projection, "f8[1]r f8[1]r f8[1]r f8[1]r f8 f8 f8 f8 b1 i8 i8"),
    "Cull": (Cull, "f8[1]r f8[2]r b1 f8 i8 i8 b1 i8[1]r"),
    "DepthSums": (DepthSums, "f8[2] i4[2] i8"),
    "Rays": (Rays, "f8[2] i8 i8 i8 i8"),
    "Sweep": (Sweep, "i8[1]r i8[1]r Rays"),
}


def _types(spec: str) -> tuple:
    """Numba types of a compact spec: ``i8`` (int64), ``f8``, ``b1`` scalars; ``f8[2]`` a
    writable C-contiguous 2-d float64 array (an output); ``f8[2]r`` one that is only read;
    a name of :data:`TUPLES`, that named tuple (its fields' arrays must have exactly these
    flags: numba converts no named tuple; :func:`_ro` makes an input read-only)."""
    out = []
    for tok in spec.split():
        if tok in TUPLES:
            cls, fields = TUPLES[tok]
            out.append(_nt.BaseTuple.from_types(_types(fields), cls))
            continue
        if "[" not in tok:
            out.append(_SCALARS[tok])
            continue
        dt, rest = tok.split("[")
        nd, flag = rest.split("]")
        out.append(_nt.Array(_DTYPES[dt], int(nd), "C", readonly=flag == "r"))
    return tuple(out)


#: Argument types of the one specialisation of each kernel (see :func:`_types`).
SIGNATURES = {
    "_first_use_rank": "f8[2]r i8[1]r b1 i8[1] f8[2] i4[1] i8[1] i8[1] i8[1] i8[1] i8[2]",
    "_project_vertices": "i8 i8 f8[2]r Projection i8[2] f8[1] b1[1] i4[1]",
    "_cull_triangles": "i8 i8 Projected Cull i1[1] i8[2] i8[1] i8[1]",
    "_raster_bands": "i8 i8 Bands Triangles Frame b1 DepthSums Sweep i8[1]",
    "_finish": "i8 i8 f8[3]r i4[3]r f8[3]r b1 Grid Rays i8",
    "_raster_direct": "i8 i8 i8 Projected Frame i8 i8 b1 f8[2]r f8[3] i8[1]",
    "_reduce_chunks": "i8 i8 f8[3]r i4[3]r f8 f8[2]",
}

#: Kernels each engine path needs (what ``KERNELS.compile(paths)`` compiles for a scene).
PATHS = {
    "setup": ("_project_vertices",),
    # (a cold start orders the meshes in NumPy: spatial_order_numpy; compiled for later runs)
    "order": ("_first_use_rank",),
    "direct": ("_raster_direct", "_reduce_chunks", "_finish"),
    "banded": ("_cull_triangles",),
    "single": ("_raster_bands", "_reduce_chunks", "_finish"),
    "multi": ("_raster_bands",),
}

#: Compile CPU seconds of each kernel beyond what a process pays for its first compile
#: (``benchmarks/compile_profile.py --opt 1``, one process per kernel, less the ~0.5 s of
#: numba's start that ``_reduce_chunks`` is nearly all of; 2026-12-05, the Xeon VM, after the
#: vectorised projection and one-body raster; ``_raster_bands`` re-measured once it computed
#: the planes itself), to share them out among the workers; kernels
#: of one tuple share helpers and go to the same worker.
_COSTS = {("_first_use_rank",): 0.6, ("_project_vertices",): 1.05, ("_cull_triangles",): 1.0,
          ("_raster_bands",): 2.5,
          ("_raster_direct",): 3.8, ("_reduce_chunks",): 0.05, ("_finish",): 0.75}
#: LLVM optimisation level of the workers' compiles (``NUMBA_OPT``, numba's default 3), unless
#: the environment sets one: level 1 compiles the kernels in less time, and the kernels
#: trace as fast and give the same bits (measured on the bundled phantoms:
#: ``benchmarks/image_hashes.py``, ``benchmarks/notes/coldstart.md``). Level 0 cannot be
#: cached (numba: "uses dynamic globals"). The cache does not record the level: a kernel
#: compiled by the process itself (no cache to share) is compiled at the process's level.
_WORKER_OPT = 1

#: Seconds of compiling that the background process of ``KERNELS.prepare`` takes on beyond this
#: process's share: its head start while this process loads the scene (~2 s for ``default``,
#: of which this process's import of numba and first load from the cache, ~0.5 s, is paid
#: anyway; ``benchmarks/notes/coldstart.md``, eighth pass).
_HEAD = 1.5


#: The kernels above, each compiled for its one signature on first use; background compiles.
KERNELS = KernelSet(
    __name__,
    {"_first_use_rank": _first_use_rank, "_project_vertices": _project_vertices,
     "_cull_triangles": _cull_triangles, "_raster_bands": _raster_bands, "_finish": _finish,
     "_raster_direct": _raster_direct, "_reduce_chunks": _reduce_chunks},
    {name: _types(spec) for name, spec in SIGNATURES.items()},
    paths=PATHS, costs=_COSTS, worker_opt=_WORKER_OPT, head=_HEAD)
