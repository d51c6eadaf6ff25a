"""Culling: which (ray, triangle) pairs can intersect at all.

Testing every ray against every triangle costs ``rays x triangles`` (hours for a 512 x 512 image
of an 80k-face mesh). Rays that share an origin (a point source) or a direction (a parallel beam)
are projected onto a plane across the beam and binned on a regular 2D grid; each triangle is
projected the same way and only meets the rays of the bins its bounding box covers (its
*footprint*). Other ray sets fall back to a bounding-box slab test in blocks.

The projection is conservative (bounding boxes are widened by a relative margin far larger than
rounding), so culling never drops a pair that the exact test would accept.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator

import numpy as np

__all__ = ["candidate_pairs"]

#: Upper bound on the pairs handled at once (memory stays O(pairs per block)).
PAIRS_PER_BLOCK = 1 << 20
_MARGIN = 1e-9


def _frame(axis):
    f = np.asarray(axis, float) / np.linalg.norm(axis)
    helper = np.eye(3)[np.argmin(np.abs(f))]
    e1 = np.cross(f, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(f, e1)
    return f, e1, e2


def candidate_pairs(triangles, origins, directions, t_min, t_max, *, axis=None,
                    block=PAIRS_PER_BLOCK, progress=None) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Yield blocks of ``(ray_index, triangle_index)`` pairs that may intersect.

    Parameters
    ----------
    triangles : (T, 3, 3) float
    origins, directions : (n, 3) float
    t_min, t_max : (n,) float
    axis : (3,) float, optional
        Beam axis used for the projection; defaults to the mean ray direction.
    block : int
        Approximate number of pairs per yielded block.
    progress : bool or None
        Show a progress bar over the blocks; None shows one only on a terminal and only for
        work of more than a few blocks.
    """
    n = len(directions)
    if n == 0 or len(triangles) == 0:
        return
    same_origin = bool(np.all(origins == origins[0]))
    same_direction = bool(np.all(directions == directions[0]))
    if same_origin or same_direction:
        perspective = same_origin
        if not perspective:
            axis = directions[0]              # orthographic: project along the rays themselves
        elif axis is None:
            axis = directions.mean(axis=0)
        if np.linalg.norm(axis) > 0:
            f, e1, e2 = _frame(axis)
            cos = (directions / np.linalg.norm(directions, axis=1)[:, None]) @ f
            if np.min(cos) > 0.05:
                yield from _binned(triangles, origins, directions, t_min, t_max, f, e1, e2,
                                   perspective=perspective, block=block, progress=progress)
                return
    yield from _brute_force(triangles, origins, directions, t_min, t_max, block=block)


def _brute_force(triangles, origins, directions, t_min, t_max, *, block):
    """Slab test of each ray against each triangle's bounding box, in blocks."""
    lo = triangles.min(axis=1)
    hi = triangles.max(axis=1)
    pad = _MARGIN * (np.abs(lo) + np.abs(hi) + 1.0)
    lo, hi = lo - pad, hi + pad
    n, T = len(directions), len(triangles)
    rays_per_block = max(1, block // max(T, 1))
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / directions
    for start in range(0, n, rays_per_block):
        sl = slice(start, min(n, start + rays_per_block))
        o, iv = origins[sl, None, :], inv[sl, None, :]
        with np.errstate(invalid="ignore"):
            t1 = (lo[None] - o) * iv
            t2 = (hi[None] - o) * iv
        # A zero direction component: inside the slab means (-inf, inf), outside means empty.
        zero = ~np.isfinite(iv) | (directions[sl, None, :] == 0)
        inside = (o >= lo[None]) & (o <= hi[None])
        tn = np.where(zero, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2)).max(axis=2)
        tf = np.where(zero, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2)).min(axis=2)
        ok = (tn <= tf) & (tf >= t_min[sl, None]) & (tn <= t_max[sl, None])
        r, t = np.nonzero(ok)
        if len(r):
            yield r + start, t


def _binned(triangles, origins, directions, t_min, t_max, f, e1, e2, *, perspective, block,
            progress=None):
    n = len(directions)
    T = len(triangles)
    o0 = origins[0]
    if perspective:
        dz = directions @ f
        qx = (directions @ e1) / dz
        qy = (directions @ e2) / dz
        rel = triangles - o0                       # (T, 3, 3)
        w = rel @ f                                # (T, 3) depth along the axis
        with np.errstate(divide="ignore", invalid="ignore"):
            px = (rel @ e1) / w
            py = (rel @ e2) / w
        behind = np.all(w < 0, axis=1)
        straddle = (np.min(w, axis=1) <= 0) & ~behind
        reach = np.max(t_max * dz) if np.all(np.isfinite(t_max)) else np.inf
        beyond = np.min(w, axis=1) > reach * (1 + 1e-9)
        cull = behind | beyond
    else:
        qx = origins @ e1
        qy = origins @ e2
        px = triangles @ e1
        py = triangles @ e2
        cull = np.zeros(T, bool)
        straddle = np.zeros(T, bool)

    x0, x1 = qx.min(), qx.max()
    y0, y1 = qy.min(), qy.max()
    span_x = max(x1 - x0, 1e-300)
    span_y = max(y1 - y0, 1e-300)
    aspect = span_x / span_y if span_y > 1e-300 else 1.0
    gx = int(np.clip(round(np.sqrt(n * aspect)), 1, 4096))
    gy = int(np.clip(round(n / gx), 1, 4096))
    if x1 == x0:
        gx = 1
    if y1 == y0:
        gy = 1
    bw_x = span_x / gx
    bw_y = span_y / gy

    def bin_x(x):
        return np.clip(np.floor((x - x0) / bw_x), -1, gx).astype(np.int64)

    def bin_y(y):
        return np.clip(np.floor((y - y0) / bw_y), -1, gy).astype(np.int64)

    rbx = np.clip(bin_x(qx), 0, gx - 1)
    rby = np.clip(bin_y(qy), 0, gy - 1)
    rbin = rby * gx + rbx
    order = np.argsort(rbin, kind="stable")
    counts = np.bincount(rbin, minlength=gx * gy)
    starts = np.concatenate([[0], np.cumsum(counts)])
    # Summed-area table of ray counts per bin, to size each triangle's pair count.
    sat = np.zeros((gy + 1, gx + 1), np.int64)
    sat[1:, 1:] = counts.reshape(gy, gx).cumsum(0).cumsum(1)

    with np.errstate(invalid="ignore"):
        lo_x, hi_x = np.nanmin(px, axis=1), np.nanmax(px, axis=1)
        lo_y, hi_y = np.nanmin(py, axis=1), np.nanmax(py, axis=1)
    pad_x = _MARGIN * (np.abs(lo_x) + np.abs(hi_x) + span_x)
    pad_y = _MARGIN * (np.abs(lo_y) + np.abs(hi_y) + span_y)
    ix0 = np.clip(bin_x(lo_x - pad_x), 0, gx)
    ix1 = np.clip(bin_x(hi_x + pad_x), -1, gx - 1)
    iy0 = np.clip(bin_y(lo_y - pad_y), 0, gy)
    iy1 = np.clip(bin_y(hi_y + pad_y), -1, gy - 1)
    # Triangles whose projection is unbounded (straddling the source plane) meet every bin.
    ix0[straddle], ix1[straddle], iy0[straddle], iy1[straddle] = 0, gx - 1, 0, gy - 1
    valid = ~cull & (straddle | (np.isfinite(lo_x) & (ix1 >= ix0) & (iy1 >= iy0)))
    ix0, ix1, iy0, iy1 = (np.where(valid, a, 0) for a in (ix0, ix1, iy0, iy1))
    nbx = np.where(valid, ix1 - ix0 + 1, 0)
    nby = np.where(valid, iy1 - iy0 + 1, 0)
    pairs_per_tri = np.where(
        valid, sat[iy1 + 1, ix1 + 1] - sat[iy0, ix1 + 1] - sat[iy1 + 1, ix0] + sat[iy0, ix0], 0)
    tri_ids = np.flatnonzero(pairs_per_tri > 0)
    if len(tri_ids) == 0:
        return
    cum = np.cumsum(pairs_per_tri[tri_ids])
    # Split the triangles into blocks of about `block` pairs.
    cuts = np.searchsorted(cum, np.arange(block, cum[-1], block), side="right")
    chunks = [c for c in np.split(tri_ids, np.unique(cuts)) if len(c)]
    if progress is None:
        # tqdm's disable=None shows a bar on a terminal only; short work shows none.
        disable = None if len(chunks) > 8 else True
    else:
        disable = not progress
    if disable is None and hasattr(sys.stderr, "isatty") and not sys.stderr.isatty():
        disable = True                # tqdm's own rule for None, without importing tqdm
    if not disable:
        from tqdm.auto import tqdm

        chunks = tqdm(chunks, desc="tracing", unit="block", leave=False, disable=disable)
    for chunk in chunks:
        nb = nbx[chunk] * nby[chunk]
        tri_rep = np.repeat(chunk, nb)
        first = np.repeat(np.cumsum(nb) - nb, nb)
        local = np.arange(len(tri_rep)) - first
        wx = nbx[tri_rep]
        bx = ix0[tri_rep] + local % wx
        by = iy0[tri_rep] + local // wx
        b = by * gx + bx
        c = counts[b]
        keep = c > 0
        tri_rep, b, c = tri_rep[keep], b[keep], c[keep]
        pair_tri = np.repeat(tri_rep, c)
        first2 = np.repeat(np.cumsum(c) - c, c)
        local2 = np.arange(len(pair_tri)) - first2
        pair_ray = order[np.repeat(starts[b], c) + local2]
        yield pair_ray, pair_tri
