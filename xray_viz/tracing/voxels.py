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

__all__ = ["voxel_sums", "grid_chords", "inverse_affine", "check_affine"]


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


@njit(cache=True, nogil=True, error_model="numpy")
def _trace(lo, hi, origins, directions, t_max, inv, classes, weights, n_classes,
           iv_start, iv_t0, iv_t1, out):
    """Rays ``lo .. hi - 1``: ``out[r, c - 1] += weight x chord`` over their voxels."""
    ni, nj, nk = classes.shape
    n_dims = np.empty(3, np.int64)
    n_dims[0], n_dims[1], n_dims[2] = ni, nj, nk
    one_origin = origins.shape[0] == 1
    one_dir = directions.shape[0] == 1
    p = np.empty(3)
    d = np.empty(3)
    idx = np.empty(3, np.int64)
    step = np.empty(3, np.int64)
    t_next = np.empty(3)
    inv_d = np.empty(3)
    for r in range(lo, hi):
        ro = 0 if one_origin else r
        rd = 0 if one_dir else r
        for a in range(3):
            p[a] = inv[a, 0] * origins[ro, 0] + inv[a, 1] * origins[ro, 1] \
                + inv[a, 2] * origins[ro, 2] + inv[a, 3]
            d[a] = inv[a, 0] * directions[rd, 0] + inv[a, 1] * directions[rd, 1] \
                + inv[a, 2] * directions[rd, 2]
        # the grid's box [-1/2, n - 1/2] in index space, by slabs
        t0 = 0.0
        t1 = t_max[r]
        for a in range(3):
            lo_a = -0.5
            hi_a = n_dims[a] - 0.5
            if d[a] == 0.0:
                if p[a] < lo_a or p[a] > hi_a:
                    t1 = -1.0
                continue
            inv_d[a] = 1.0 / d[a]
            ta = (lo_a - p[a]) * inv_d[a]
            tb = (hi_a - p[a]) * inv_d[a]
            if ta > tb:
                ta, tb = tb, ta
            if ta > t0:
                t0 = ta
            if tb < t1:
                t1 = tb
        if not t0 < t1:
            continue
        # the first voxel: where the ray is half-way into its first stretch... found from the
        # entry point, each index clamped into the grid (the entry lies on its face)
        for a in range(3):
            x = p[a] + t0 * d[a]
            m = np.int64(np.floor(x + 0.5))
            if m < 0:
                m = 0
            if m > n_dims[a] - 1:
                m = n_dims[a] - 1
            idx[a] = m
            if d[a] > 0.0:
                step[a] = 1
                t_next[a] = (m + 0.5 - p[a]) * inv_d[a]
            elif d[a] < 0.0:
                step[a] = -1
                t_next[a] = (m - 0.5 - p[a]) * inv_d[a]
            else:
                step[a] = 0
                t_next[a] = np.inf
        # this ray's intervals to leave out
        j = iv_start[r]
        j_end = iv_start[r + 1]
        t = t0
        while t < t1:
            a = 0
            if t_next[1] < t_next[a]:
                a = 1
            if t_next[2] < t_next[a]:
                a = 2
            tn = t_next[a]
            if tn > t1:
                tn = t1
            if tn > t:
                c = classes[idx[0], idx[1], idx[2]]
                if c != 0:
                    chord = tn - t
                    while j < j_end and iv_t1[j] <= t:
                        j += 1
                    jj = j
                    while jj < j_end and iv_t0[jj] < tn:
                        s0 = iv_t0[jj] if iv_t0[jj] > t else t
                        s1 = iv_t1[jj] if iv_t1[jj] < tn else tn
                        if s1 > s0:
                            chord -= s1 - s0
                        jj += 1
                    if chord > 0.0:
                        out[r, c - 1] += weights[idx[0], idx[1], idx[2]] * chord
                t = tn
            idx[a] += step[a]
            if idx[a] < 0 or idx[a] >= n_dims[a]:
                break
            t_next[a] = (idx[a] + 0.5 * step[a] - p[a]) * inv_d[a]
    return 0


def voxel_sums(origins, directions, t_max, affine, classes, weights, *, n_classes: int,
               intervals=None, out=None, threads: int | None = None) -> np.ndarray:
    """Per ray and class, ``sum of weight x chord`` (mm x weight) over the grid's voxels.

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

    Returns
    -------
    (n, n_classes) float64
    """
    from xray_viz import _threads

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

    def piece(q):
        return _trace(bounds[q], bounds[q + 1], origins, directions, t_max, inv, classes,
                      weights, int(n_classes), start, iv0, iv1, out)

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
