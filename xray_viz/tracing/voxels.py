"""Exact voxel traversal: each ray's chord in each voxel of a grid (Siddon / Jacobs).

A volume is a grid of voxels with an affine from voxel index to world mm (voxel ``(i, j, k)``
is the parallelepiped of index-space points within half a voxel of ``(i, j, k)``: any affine,
rotated, anisotropic or sheared). A ray ``o + t d`` (``|d| = 1``, ``t`` in mm) is mapped into
index space by the inverse affine, where it is still linear in the same ``t``; the planes
between voxels are then ``index = m + 1/2`` and the ray crosses them in order of ``t``. The
stretch between two consecutive crossings lies in one voxel, and its length (in mm, as ``t``)
is that voxel's chord: Siddon's exact radiological path (R. L. Siddon, Med. Phys. 12 (1985)
252) visited in the incremental order of Jacobs et al. (1998) / Amanatides and Woo, with each
crossing computed afresh from the plane (no accumulated increments), so a chord is exact to
a few ulps of ``t``.

Each voxel holds a *class* (``uint8``; 0 is empty: nothing attenuates there) and a *weight*
(its density in g/cm3 for a CT, 1 for a label map). The kernel accumulates, per ray and per
class, ``sum over the voxels of that class of weight x chord``: ``(n_rays, n_classes)``. Times
``mu(E) / rho`` per class (1/cm per g/cm3) that is every energy's line integral by one matrix
product, as the path lengths of meshes are (:mod:`xray_viz.physics.imaging`): the geometry is
traced once for a whole spectrum.

Meshes inside the volume *replace* its material where they are: each ray may carry a sorted
list of disjoint intervals ``[t0, t1)`` (where it is inside a mesh body); the part of every
voxel chord inside them is left out, exactly (:func:`voxel_sums`).

The kernel runs on the library's one pool of threads, one contiguous piece of rays per thread
(``nogil``; numba's own threading layer is not started, as for the fast engine's kernels).

Examples
--------
A 4 x 4 x 4 grid of 2 mm voxels, class 1 with density 1.5; a ray along x through it:

>>> import numpy as np
>>> affine = np.diag([2.0, 2.0, 2.0, 1.0])
>>> classes = np.ones((4, 4, 4), np.uint8); weights = np.full((4, 4, 4), 1.5, np.float32)
>>> out = voxel_sums(np.array([[-10.0, 3.1, 2.9]]), np.array([[1.0, 0.0, 0.0]]),
...                  np.array([100.0]), affine, classes, weights, n_classes=1)
>>> out.tolist()                    # 8 mm of density 1.5
[[12.0]]
"""

from __future__ import annotations

import numpy as np
from numba import njit

from xray_viz.errors import SceneError
from xray_viz.tracing import _numba_cache  # noqa: F401  (where the kernels below are cached)

__all__ = ["voxel_sums", "grid_chords", "inverse_affine", "check_affine", "classify",
           "INTERPOLATIONS"]


def check_affine(affine, *, where: str = "volume") -> np.ndarray:
    """A finite, invertible 4 x 4 voxel-to-world affine, as float64; else one line.

    Raises
    ------
    SceneError
        Not 4 x 4, not finite, last row not ``[0, 0, 0, 1]``, or singular (a voxel of no
        volume: the grid's determinant below 1e-12 of its spacing's product).

    Examples
    --------
    >>> check_affine(np.diag([1.0, 0.0, 1.0, 1.0]), where="ct.nii")
    Traceback (most recent call last):
    ...
    xray_viz.errors.SceneError: ct.nii: its voxel-to-world affine is singular (a voxel of zero volume); fix the file's spacing or direction
    """
    a = np.asarray(affine, dtype=np.float64)
    if a.shape != (4, 4):
        raise SceneError(f"{where}: its voxel-to-world affine must be 4 x 4, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise SceneError(f"{where}: its voxel-to-world affine holds NaN or infinite values; fix "
                         "the file's header (spacing, origin, direction)")
    if not np.allclose(a[3], [0, 0, 0, 1]):
        raise SceneError(f"{where}: its affine's last row must be [0, 0, 0, 1], got "
                         f"{a[3].tolist()}")
    spacing = np.linalg.norm(a[:3, :3], axis=0)
    if not (np.all(spacing > 0)
            and abs(np.linalg.det(a[:3, :3])) > 1e-12 * float(np.prod(spacing))):
        raise SceneError(f"{where}: its voxel-to-world affine is singular (a voxel of zero "
                         "volume); fix the file's spacing or direction")
    return a


def inverse_affine(affine) -> np.ndarray:
    """The world-to-index affine (3 x 4, float64) of a voxel-to-world 4 x 4 affine."""
    return np.ascontiguousarray(np.linalg.inv(check_affine(affine))[:3])



@njit(inline="always")
def _slab(p, e, n, t0, t1):
    """``(t0, t1, 1/e)``: ``[t0, t1]`` cut to where ``p + t e`` is in ``[-1/2, n - 1/2]``
    (one axis of a grid's box in index space); ``t0 > t1`` if never; ``1/e`` 0 for ``e = 0``."""
    if e != 0.0:
        ie = 1.0 / e
        ta = (-0.5 - p) * ie
        tb = (n - 0.5 - p) * ie
        return max(t0, min(ta, tb)), min(t1, max(ta, tb)), ie
    if p < -0.5 or p > n - 0.5:
        return 1.0, 0.0, 0.0
    return t0, t1, 0.0


@njit(inline="always")
def _grid_entry(inv, o, d, t_max, ni, nj, nk):
    """A ray ``o + t d`` in a grid's index space: ``(px, py, pz, ex, ey, ez, ix, iy, iz, t0,
    t1)``, the origin and direction there, the direction's inverses (0 along an axis it does
    not move on) and where it is inside the grid's box ``[-1/2, n - 1/2]`` (by slabs) within
    ``[0, t_max]``; ``t0 >= t1``: never. The one copy of this step for every voxel kernel."""
    ox, oy, oz = o[0], o[1], o[2]
    dx, dy, dz = d[0], d[1], d[2]
    px = inv[0, 0] * ox + inv[0, 1] * oy + inv[0, 2] * oz + inv[0, 3]
    py = inv[1, 0] * ox + inv[1, 1] * oy + inv[1, 2] * oz + inv[1, 3]
    pz = inv[2, 0] * ox + inv[2, 1] * oy + inv[2, 2] * oz + inv[2, 3]
    ex = inv[0, 0] * dx + inv[0, 1] * dy + inv[0, 2] * dz
    ey = inv[1, 0] * dx + inv[1, 1] * dy + inv[1, 2] * dz
    ez = inv[2, 0] * dx + inv[2, 1] * dy + inv[2, 2] * dz
    t0, t1, ix = _slab(px, ex, ni, 0.0, t_max)
    t0, t1, iy = _slab(py, ey, nj, t0, t1)
    t0, t1, iz = _slab(pz, ez, nk, t0, t1)
    return px, py, pz, ex, ey, ez, ix, iy, iz, t0, t1


@njit(cache=True, nogil=True, error_model="numpy")
def _trace(lo, hi, rays, grid, intervals, n_classes, out):
    """Rays ``lo .. hi - 1``: ``out[r, c - 1] += weight x chord`` over their voxels.

    ``rays`` is ``(origins, directions, t_max)``, ``grid`` ``(inv, classes, weights)`` and
    ``intervals`` ``(iv_start, iv_t0, iv_t1)`` (:func:`voxel_sums`'s, in its order).

    ``classes`` and ``weights`` are flat (C order of the (I, J, K) grid, ``out``'s last two
    arguments' shape in ``inv``'s companion ``dims``): the walk steps a flat index by the
    axis' stride. Each ray sums into a small local array (class 0 included, dropped)."""
    origins, directions, t_max = rays
    inv, classes, weights = grid
    iv_start, iv_t0, iv_t1 = intervals
    ni = np.int64(inv[0, 4])
    nj = np.int64(inv[1, 4])
    nk = np.int64(inv[2, 4])
    one_origin = origins.shape[0] == 1
    one_dir = directions.shape[0] == 1
    acc = np.zeros(n_classes + 1)
    for r in range(lo, hi):
        ro = 0 if one_origin else r
        rd = 0 if one_dir else r
        px, py, pz, ex, ey, ez, ix, iy, iz, t0, t1 = _grid_entry(
            inv, origins[ro], directions[rd], t_max[r], ni, nj, nk)
        if not t0 < t1:
            continue
        # the first voxel: the entry point's, each index clamped into the grid (the entry
        # lies on a face of the grid); a ray in a plane between voxels takes the + side
        i = min(max(np.int64(np.floor(px + t0 * ex + 0.5)), 0), ni - 1)
        j = min(max(np.int64(np.floor(py + t0 * ey + 0.5)), 0), nj - 1)
        k = min(max(np.int64(np.floor(pz + t0 * ez + 0.5)), 0), nk - 1)
        si = 1 if ex > 0.0 else -1
        sj = 1 if ey > 0.0 else -1
        sk = 1 if ez > 0.0 else -1
        tx = (i + 0.5 * si - px) * ix if ex != 0.0 else np.inf
        ty = (j + 0.5 * sj - py) * iy if ey != 0.0 else np.inf
        tz = (k + 0.5 * sk - pz) * iz if ez != 0.0 else np.inf
        flat = (i * nj + j) * nk + k
        di = si * nj * nk
        dj = sj * nk
        dk = sk
        for c in range(n_classes + 1):
            acc[c] = 0.0
        q = iv_start[r]
        q_end = iv_start[r + 1]
        t = t0
        while True:
            if tx <= ty and tx <= tz:
                tn = tx
                axis = 0
            elif ty <= tz:
                tn = ty
                axis = 1
            else:
                tn = tz
                axis = 2
            end = tn >= t1
            if end:
                tn = t1
            chord = tn - t
            if q < q_end:                       # stretches inside meshes: left out
                while q < q_end and iv_t1[q] <= t:
                    q += 1
                qq = q
                while qq < q_end and iv_t0[qq] < tn:
                    s0 = max(iv_t0[qq], t)
                    s1 = min(iv_t1[qq], tn)
                    if s1 > s0:
                        chord -= s1 - s0
                    qq += 1
                if chord < 0.0:
                    chord = 0.0
            acc[classes[flat]] += weights[flat] * chord
            if end:
                break
            t = tn
            if axis == 0:
                i += si
                if i < 0 or i >= ni:
                    break
                flat += di
                tx = (i + 0.5 * si - px) * ix
            elif axis == 1:
                j += sj
                if j < 0 or j >= nj:
                    break
                flat += dj
                ty = (j + 0.5 * sj - py) * iy
            else:
                k += sk
                if k < 0 or k >= nk:
                    break
                flat += dk
                tz = (k + 0.5 * sk - pz) * iz
        for c in range(n_classes):
            out[r, c] += acc[c + 1]
    return 0


#: The values of ``interpolation``: each voxel's value over its whole voxel (the default), or
#: the trilinear interpolation between voxel centres.
INTERPOLATIONS = ("nearest", "trilinear")


@njit(cache=True, nogil=True, inline="always")
def _simpson(acc, ta, tb, p, e, n, classes, weights):
    """The exact integral over ``t`` in ``[ta, tb]`` of the trilinear field of every class,
    for a stretch inside one dual cell (the eight voxels around it fixed): there the field is
    a product of three linear functions of ``t`` (a cubic), which Simpson's rule integrates
    exactly. Each of the eight voxels gets ``(tb - ta) / 6 x (w(a) + 4 w(m) + w(b))`` of its
    weight, ``w`` its trilinear weight at the stretch's ends and middle. The point is clamped
    into ``[0, n - 1]`` along each axis (constant in the box's outer half voxel). ``p``, ``e``
    and ``n``: the ray's origin and direction in index space and the grid's dimensions, each
    a 3-tuple."""
    if not tb > ta:
        return
    px, py, pz = p
    ex, ey, ez = e
    ni, nj, nk = n
    tm = 0.5 * (ta + tb)
    xa = min(max(px + ta * ex, 0.0), ni - 1.0)
    ya = min(max(py + ta * ey, 0.0), nj - 1.0)
    za = min(max(pz + ta * ez, 0.0), nk - 1.0)
    xm = min(max(px + tm * ex, 0.0), ni - 1.0)
    ym = min(max(py + tm * ey, 0.0), nj - 1.0)
    zm = min(max(pz + tm * ez, 0.0), nk - 1.0)
    xb = min(max(px + tb * ex, 0.0), ni - 1.0)
    yb = min(max(py + tb * ey, 0.0), nj - 1.0)
    zb = min(max(pz + tb * ez, 0.0), nk - 1.0)
    ci = max(min(np.int64(np.floor(xm)), ni - 2), 0)
    cj = max(min(np.int64(np.floor(ym)), nj - 2), 0)
    ck = max(min(np.int64(np.floor(zm)), nk - 2), 0)
    h = (tb - ta) / 6.0
    # the upper corner's weight along each axis at a, m, b (the lower one's: 1 - it)
    ua, um, ub = xa - ci, xm - ci, xb - ci
    va, vm, vb = ya - cj, ym - cj, yb - cj
    wa, wm, wb = za - ck, zm - ck, zb - ck
    for a in range(2):
        if a == 1 and ci + 1 >= ni:
            break
        xa_ = ua if a else 1.0 - ua
        xm_ = um if a else 1.0 - um
        xb_ = ub if a else 1.0 - ub
        for b in range(2):
            if b == 1 and cj + 1 >= nj:
                break
            ya_ = xa_ * (va if b else 1.0 - va)
            ym_ = xm_ * (vm if b else 1.0 - vm)
            yb_ = xb_ * (vb if b else 1.0 - vb)
            for c in range(2):
                if c == 1 and ck + 1 >= nk:
                    break
                g = (ya_ * (wa if c else 1.0 - wa) + 4.0 * ym_ * (wm if c else 1.0 - wm)
                     + yb_ * (wb if c else 1.0 - wb))
                if g != 0.0:
                    flat = ((ci + a) * nj + (cj + b)) * nk + (ck + c)
                    acc[classes[flat]] += h * g * weights[flat]


@njit(cache=True, nogil=True, error_model="numpy")
def _trace_trilinear(lo, hi, rays, grid, intervals, n_classes, out):
    """Rays ``lo .. hi - 1``: ``out[r, c - 1] +=`` the line integral of class c's trilinear
    field (each voxel's weight where its class is c, 0 elsewhere, interpolated between the
    voxel centres), over the grid's box; the stretches inside meshes left out.

    The ray is cut at every plane through voxel centres (whole indices in index space); in
    each piece the interpolation's eight voxels are fixed and the field is a cubic in ``t``,
    integrated exactly by Simpson's rule (:func:`_simpson`). The arguments: :func:`_trace`'s."""
    origins, directions, t_max = rays
    inv, classes, weights = grid
    iv_start, iv_t0, iv_t1 = intervals
    ni = np.int64(inv[0, 4])
    nj = np.int64(inv[1, 4])
    nk = np.int64(inv[2, 4])
    one_origin = origins.shape[0] == 1
    one_dir = directions.shape[0] == 1
    acc = np.zeros(n_classes + 1)
    for r in range(lo, hi):
        ro = 0 if one_origin else r
        rd = 0 if one_dir else r
        px, py, pz, ex, ey, ez, ix, iy, iz, t0, t1 = _grid_entry(
            inv, origins[ro], directions[rd], t_max[r], ni, nj, nk)
        if not t0 < t1:
            continue
        # the next plane through voxel centres (a whole index) ahead along each axis
        xs = px + t0 * ex
        ys = py + t0 * ey
        zs = pz + t0 * ez
        if ex > 0.0:
            mx = np.floor(xs) + 1.0
            sx = 1.0
        else:
            mx = np.ceil(xs) - 1.0
            sx = -1.0
        if ey > 0.0:
            my = np.floor(ys) + 1.0
            sy = 1.0
        else:
            my = np.ceil(ys) - 1.0
            sy = -1.0
        if ez > 0.0:
            mz = np.floor(zs) + 1.0
            sz = 1.0
        else:
            mz = np.ceil(zs) - 1.0
            sz = -1.0
        tx = (mx - px) * ix if ex != 0.0 else np.inf
        ty = (my - py) * iy if ey != 0.0 else np.inf
        tz = (mz - pz) * iz if ez != 0.0 else np.inf
        for c in range(n_classes + 1):
            acc[c] = 0.0
        q = iv_start[r]
        q_end = iv_start[r + 1]
        t = t0
        while t < t1:
            tn = min(tx, ty, tz, t1)
            if tn > t:
                # [t, tn] less the stretches inside meshes
                s = t
                while q < q_end and iv_t1[q] <= s:
                    q += 1
                qq = q
                while qq < q_end and iv_t0[qq] < tn:
                    if iv_t0[qq] > s:
                        _simpson(acc, s, iv_t0[qq], (px, py, pz), (ex, ey, ez), (ni, nj, nk),
                                 classes, weights)
                    s = max(s, iv_t1[qq])
                    qq += 1
                if s < tn:
                    _simpson(acc, s, tn, (px, py, pz), (ex, ey, ez), (ni, nj, nk), classes,
                             weights)
                t = tn
            if tx <= tn:
                mx += sx
                tx = (mx - px) * ix
            if ty <= tn:
                my += sy
                ty = (my - py) * iy
            if tz <= tn:
                mz += sz
                tz = (mz - pz) * iz
        for c in range(n_classes):
            out[r, c] += acc[c + 1]
    return 0


@njit(cache=True, nogil=True, error_model="numpy")
def _classify(values, lo, hi, a, b, classes, weights, low_rho):
    """One pass: each value's class (the first range ``lo <= v < hi``, 1-based; 0 none) and
    weight ``a + b v`` of its class; ``low_rho[c]`` the smallest weight of class c."""
    n_ranges = lo.shape[0]
    for q in range(values.shape[0]):
        v = values[q]
        c = 0
        for m in range(n_ranges):
            if v >= lo[m] and v < hi[m]:
                c = m + 1
                break
        classes[q] = c
        if c:
            w = a[c - 1] + b[c - 1] * v
            weights[q] = w
            if w < low_rho[c - 1]:
                low_rho[c - 1] = w
        else:
            weights[q] = 0.0
    return 0


def classify(values, ranges, *, dtype=np.float32):
    """Class and weight of every voxel, in one pass (numba, the library's threads).

    Parameters
    ----------
    values : C-contiguous array
        Any shape (a CT in HU).
    ranges : sequence of (low, high, a, b)
        Class k (1-based) is the first range with ``low <= value < high``; its weight is
        ``a + b x value`` (``b = 0``: a constant).
    dtype : float32 or float64
        Of the weights.

    Returns
    -------
    classes : uint8 array, weights : array, lowest : (n_ranges,) float
        ``lowest[k - 1]``: the smallest weight of class k (inf if it has no voxel).

    Examples
    --------
    >>> c, w, low = classify(np.array([-1000.0, 40.0, 1200.0]),
    ...                      [(-950, 120, 1.0, 1e-3), (120, np.inf, 1.017, 0.592e-3)])
    >>> c.tolist(), np.round(w.astype(float), 4).tolist(), np.round(low, 4).tolist()
    ([0, 1, 2], [0.0, 1.04, 1.7274], [1.04, 1.7274])
    """
    from xray_viz import _threads

    values = np.asarray(values)
    flat = values.reshape(-1)
    if flat.dtype not in (np.float32, np.float64):
        flat = flat.astype(np.float64)
    r = np.asarray(ranges, dtype=np.float64).reshape(-1, 4)
    lo, hi, a, b = (np.ascontiguousarray(r[:, m]) for m in range(4))
    classes = np.empty(flat.shape, np.uint8)
    weights = np.empty(flat.shape, dtype)
    n = len(flat)
    k = max(1, min(_threads.count(), n // (1 << 20) or 1))
    bounds = np.linspace(0, n, k + 1).astype(np.int64)
    lows = np.full((k, len(r)), np.inf)

    def piece(q):
        s0, s1 = bounds[q], bounds[q + 1]
        return _classify(flat[s0:s1], lo, hi, a, b, classes[s0:s1], weights[s0:s1], lows[q])

    _threads.run_pieces(piece, k)
    return classes.reshape(values.shape), weights.reshape(values.shape), lows.min(axis=0)


def voxel_sums(origins, directions, t_max, affine, classes, weights, *, n_classes: int,
               intervals=None, out=None, threads: int | None = None,
               interpolation: str = "nearest") -> np.ndarray:
    """Per ray and class, ``sum of weight x chord`` (mm x weight) over the grid's voxels.

    With ``interpolation="trilinear"``, instead the exact line integral of each class's
    trilinear field: the field of class c is each voxel's weight where its class is c and 0
    where it is another, interpolated trilinearly between the voxel centres (clamped to the
    outermost centres in the box's outer half voxel; nothing outside the box). The classes'
    fields add up to the trilinear interpolation of the weights, and ``mu/rho`` of each class
    times its column to the line integral of the trilinear interpolation of ``mu`` at every
    energy. Integrated exactly: the ray is cut where it crosses the planes through voxel
    centres, and in each piece the field, a cubic in ``t``, by Simpson's rule.

    Parameters
    ----------
    origins, directions : (n, 3) or (1, 3) float
        Rays ``o + t d``; directions of unit length (``t`` in mm). A single row is shared by
        every ray (a point source, or a parallel beam's one direction).
    t_max : (n,) float
        Where each ray ends (the detector); rays start at ``t = 0``.
    affine : (4, 4) float
        Voxel index -> world mm (voxel centres at whole indices).
    classes : (I, J, K) uint8
        Class of each voxel, 1 .. ``n_classes``; 0 attenuates nothing.
    weights : (I, J, K) float32 or float64
        Weight of each voxel (its density, or 1).
    n_classes : int
    intervals : (start, t0, t1), optional
        Stretches of each ray to leave out (meshes replacing the volume there): ray ``r``'s
        are ``[t0[q], t1[q])`` for ``q`` in ``start[r] .. start[r + 1] - 1``, sorted and
        disjoint; ``start`` has ``n + 1`` entries.
    out : (n, n_classes) float64, optional
        Added to (zeros by default).
    threads : int, optional
        Pieces of rays run in parallel (default: the library's thread count).
    interpolation : {"nearest", "trilinear"}
        Each voxel's weight over its whole voxel (the default: exact voxels, Siddon), or the
        trilinear interpolation between voxel centres, integrated exactly.

    Returns
    -------
    (n, n_classes) float64

    Examples
    --------
    Two 1 mm voxels of weights 1 and 3 along x; a ray from the first centre (x = 0) to its
    voxel's face (x = 0.5): the nearest voxel gives 0.5 x 1, the trilinear field 1 + 2x
    gives 0.5 + 0.25:

    >>> affine = np.eye(4)
    >>> classes = np.ones((2, 1, 1), np.uint8)
    >>> weights = np.array([1.0, 3.0]).reshape(2, 1, 1)
    >>> ray = (np.array([[0.0, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]), np.array([0.5]))
    >>> [round(float(voxel_sums(*ray, affine, classes, weights, n_classes=1,
    ...                         interpolation=m)[0, 0]), 12) for m in ("nearest", "trilinear")]
    [0.5, 0.75]
    """
    from xray_viz import _threads

    if interpolation not in INTERPOLATIONS:
        raise SceneError(f"voxel_sums: interpolation must be one of {list(INTERPOLATIONS)}, "
                         f"got {interpolation!r}")

    origins = np.ascontiguousarray(np.atleast_2d(origins), dtype=np.float64)
    directions = np.ascontiguousarray(np.atleast_2d(directions), dtype=np.float64)
    t_max = np.ascontiguousarray(t_max, dtype=np.float64).reshape(-1)
    n = len(t_max)
    inv = inverse_affine(affine)
    classes = np.asarray(classes)
    if classes.dtype != np.uint8 or classes.ndim != 3:
        raise SceneError("voxel_sums: classes must be a 3D uint8 array")
    weights = np.asarray(weights)
    if weights.dtype not in (np.float32, np.float64) or weights.shape != classes.shape:
        raise SceneError("voxel_sums: weights must be float32 or float64, shaped as classes")
    if out is None:
        out = np.zeros((n, max(1, int(n_classes))))
    if intervals is None:
        start = np.zeros(n + 1, np.int64)
        iv0 = iv1 = np.zeros(0)
    else:
        start, iv0, iv1 = (np.ascontiguousarray(x, dtype=dt) for x, dt in
                           zip(intervals, (np.int64, np.float64, np.float64)))
        if start.shape != (n + 1,):
            raise SceneError("voxel_sums: intervals' start must have one entry per ray + 1")
    if n == 0:
        return out
    k = max(1, min(_threads.count() if threads is None else int(threads), n // 256 or 1))
    bounds = np.linspace(0, n, k + 1).astype(np.int64)

    # the inverse affine with the grid's dimensions as a fifth column (one argument)
    inv_dims = np.ascontiguousarray(np.c_[inv, np.asarray(classes.shape, np.float64)])
    flat_classes = np.ascontiguousarray(classes).reshape(-1)
    flat_weights = np.ascontiguousarray(weights).reshape(-1)

    kernel = _trace if interpolation == "nearest" else _trace_trilinear

    def piece(q):
        return kernel(bounds[q], bounds[q + 1], (origins, directions, t_max),
                      (inv_dims, flat_classes, flat_weights), (start, iv0, iv1),
                      int(n_classes), out)

    _threads.run_pieces(piece, k)
    return out


def grid_chords(origins, directions, t_max, affine, shape):
    """Every (ray, voxel, chord) of rays through a grid, in NumPy: the reference the kernel is
    tested against (slow; small grids only).

    Returns
    -------
    ray : (m,) int
    voxel : (m, 3) int
    chord : (m,) float
        The voxels each ray crosses with a chord > 0, in order of ``t``.
    """
    inv = inverse_affine(affine)
    origins = np.atleast_2d(np.asarray(origins, dtype=np.float64))
    directions = np.atleast_2d(np.asarray(directions, dtype=np.float64))
    t_max = np.asarray(t_max, dtype=np.float64).reshape(-1)
    n = len(t_max)
    origins = np.broadcast_to(origins, (n, 3))
    directions = np.broadcast_to(directions, (n, 3))
    rays, voxels, chords = [], [], []
    shape = np.asarray(shape)
    for r in range(n):
        p = inv[:, :3] @ origins[r] + inv[:, 3]
        d = inv[:, :3] @ directions[r]
        ts = [0.0, t_max[r]]
        for a in range(3):
            if d[a] != 0:
                planes = np.arange(shape[a] + 1) - 0.5
                ts.extend(((planes - p[a]) / d[a]).tolist())
        ts = np.unique(np.clip(ts, 0.0, t_max[r]))
        mids = 0.5 * (ts[1:] + ts[:-1])
        pts = p[None, :] + mids[:, None] * d[None, :]
        m = np.floor(pts + 0.5).astype(np.int64)
        ok = np.all((m >= 0) & (m < shape), axis=1) & (np.diff(ts) > 0)
        rays.extend([r] * int(ok.sum()))
        voxels.extend(m[ok].tolist())
        chords.extend(np.diff(ts)[ok].tolist())
    return (np.asarray(rays, np.int64), np.asarray(voxels, np.int64).reshape(-1, 3),
            np.asarray(chords, np.float64))
