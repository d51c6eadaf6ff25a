"""The transport loop: one batch of photon histories, physics, geometry, source and tallies
meeting in one kernel (numba, without the GIL, one batch per thread).

Per flight: the distance to the next interaction (``-ln(1 - r) / mu_total`` of the region's
material), the next surface crossing (``geometry.next_crossing``),
the detector plane and the world's box; the nearest decides. A crossing updates the photon's
entries minus exits per body (its region is then the winner of the precedence); the detector
absorbs the photon and scores its energy in one of four images by its history; leaving the
world's box is escape. Interactions: photoelectric (deposit ``E``, end), incoherent (deposit
``E - E'``), coherent; below the cut-off the photon deposits what it has.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

import xray_viz.tracing._numba_cache  # noqa: F401  (the kernels' one disk cache)

from xray_viz.montecarlo.geometry import next_crossing, region_of
from xray_viz.montecarlo.physics import CUTOFF_KEV, mu_lookup, sample_coherent, sample_incoherent
from xray_viz.montecarlo.rng import uniform
from xray_viz.montecarlo.sources import sample_direction, sample_energy

__all__ = ["TOTALS", "TRACK_ENDS"]    # and the kernel ``run_batch``

#: Entries of a batch's ``totals`` (keV summed over its histories; ``*_sq`` of the per-history
#: values).
TOTALS = ("emitted", "detector", "detector_sq", "escaped", "deposited", "histories",
          "deposited_sq")
#: What ended a recorded track (``trk_end``'s codes, in order).
TRACK_ENDS = ("primary", "scattered", "escaped", "absorbed")


class Emission(NamedTuple):
    """Where :func:`run_batch`'s photons start and with what energy
    (:func:`~xray_viz.montecarlo.sources.sample_direction`,
    :func:`~xray_viz.montecarlo.sources.sample_energy`)."""

    #: The source and the field it lights, flattened (:func:`~xray_viz.montecarlo.sources.field`).
    fa: np.ndarray
    #: The spectrum's energies (keV).
    energies: np.ndarray
    #: Its cumulative distribution.
    cdf: np.ndarray


class Volumes(NamedTuple):
    """The voxel volumes as :func:`run_batch` reads them (``V`` of them; none: ``V = 0``)."""

    #: ``(V, 3, 4)``: world-to-index affines.
    inv: np.ndarray
    #: ``(V, 3)``: the grids' dimensions.
    dims: np.ndarray
    #: ``(V,)``: where each grid's voxels begin in ``classes`` and ``weights``.
    start: np.ndarray
    #: The grids' classes, flattened one after the other.
    classes: np.ndarray
    #: The grids' weights, likewise.
    weights: np.ndarray
    #: ``(V,)``: region (row of the tables' ``mu``) of class ``c`` is ``region0[v] + c``.
    region0: np.ndarray
    #: ``(V, B)``: the mesh bodies that replace the volume's material where they are.
    displace: np.ndarray
    #: ``(V, 3, N)``: the majorant of the volume's voxels (row 0).
    majorant: np.ndarray


class Tracks(NamedTuple):
    """The recorded tracks of the first histories (:func:`run_batch`)."""

    #: ``(n, K, 3)``: each track's vertices.
    xyz: np.ndarray
    #: ``(n,)``: how many vertices each has.
    n: np.ndarray
    #: ``(n,)``: what ended it (:data:`TRACK_ENDS`).
    end: np.ndarray


class Tables(NamedTuple):
    """The regions' interaction data on a log-energy grid
    (:class:`~xray_viz.montecarlo.physics.MaterialTables`' arrays)."""

    #: Attenuation per region (:func:`~xray_viz.montecarlo.physics.mu_lookup`).
    mu: np.ndarray
    #: The grid's first log-energy.
    ln_e0: float
    #: Its step.
    d_ln_e: float
    #: Incoherent scattering functions per region.
    sf: np.ndarray
    #: Cumulative squared form factors per region (coherent scattering).
    cum: np.ndarray
    #: The momentum-transfer grid of ``sf`` and ``cum``.
    dx: float


class Scores(NamedTuple):
    """What :func:`run_batch` adds into (a batch's :class:`~xray_viz.montecarlo.tallies.Tallies`)."""

    #: ``(2, R)``: energy per region and its per-history squares.
    dep: np.ndarray
    #: ``(4, H, W)``: primary, single incoherent, single coherent, multiple.
    img: np.ndarray
    #: ``(4, H, W)``: the per-history squares.
    img_sq: np.ndarray
    #: :data:`TOTALS`.
    totals: np.ndarray


@numba.njit(inline="always")
def _rotate(d, cost, phi):
    """Turn the unit direction ``d`` by the polar angle ``acos(cost)`` and azimuth ``phi``."""
    sint = math.sqrt(max(0.0, 1.0 - cost * cost))
    cp, sp = math.cos(phi), math.sin(phi)
    ux, uy, uz = d[0], d[1], d[2]
    if abs(uz) > 0.99999999:
        s = 1.0 if uz > 0 else -1.0
        d[0] = sint * cp
        d[1] = sint * sp
        d[2] = s * cost
        return
    den = math.sqrt(1.0 - uz * uz)
    d[0] = ux * cost + sint * (ux * uz * cp - uy * sp) / den
    d[1] = uy * cost + sint * (uy * uz * cp + ux * sp) / den
    d[2] = uz * cost - sint * den * cp
    nrm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    d[0] /= nrm
    d[1] /= nrm
    d[2] /= nrm


@numba.njit(inline="always")
def _box_exit(o, d, lo, hi):
    t = np.inf
    for k in range(3):
        if d[k] > 0.0:
            t = min(t, (hi[k] - o[k]) / d[k])
        elif d[k] < 0.0:
            t = min(t, (lo[k] - o[k]) / d[k])
    return t


@numba.njit(inline="always")
def _grid_span(o, d, inv, dims):
    """``(t0, t1)``: where the ray ``o + t d`` is inside a voxel grid's box (index space
    ``[-1/2, n - 1/2]`` per axis, ``inv`` the world-to-index 3 x 4 affine); ``t0 >= t1``:
    never."""
    t0 = -np.inf
    t1 = np.inf
    for a in range(3):
        p = inv[a, 0] * o[0] + inv[a, 1] * o[1] + inv[a, 2] * o[2] + inv[a, 3]
        e = inv[a, 0] * d[0] + inv[a, 1] * d[1] + inv[a, 2] * d[2]
        if e != 0.0:
            ta = (-0.5 - p) / e
            tb = (dims[a] - 0.5 - p) / e
            t0 = max(t0, min(ta, tb))
            t1 = min(t1, max(ta, tb))
        elif p < -0.5 or p > dims[a] - 0.5:
            return np.inf, -np.inf
    return t0, t1


@numba.njit(inline="always")
def _voxel(x, y, z, inv, dims):
    """The flat (C order) index of the voxel holding the point (clamped into the grid)."""
    q = 0
    for a in range(3):
        f = inv[a, 0] * x + inv[a, 1] * y + inv[a, 2] * z + inv[a, 3]
        i = np.int64(math.floor(f + 0.5))
        i = min(max(i, 0), dims[a] - 1)
        q = q * dims[a] + i
    return q


@numba.njit(inline="always")
def _track(trk_xyz, trk_n, h, x, y, z):
    """Append a vertex to track ``h`` (the last slot is kept for the end)."""
    k = trk_n[h]
    if k >= trk_xyz.shape[1]:
        k = trk_xyz.shape[1] - 1
    trk_xyz[h, k, 0] = x
    trk_xyz[h, k, 1] = y
    trk_xyz[h, k, 2] = z
    trk_n[h] = k + 1


@numba.njit(inline="always")
def _seg(k, f0, f1):
    """The mean of ``exp(-k f)`` along a linear ``f`` from ``f0`` to ``f1``."""
    z = abs(k) * abs(f1 - f0)
    low = min(f0, f1) if k >= 0.0 else max(f0, f1)
    phi = 1.0 - 0.5 * z if z < 1e-8 else -math.expm1(-z) / z
    return math.exp(-k * low) * phi


@numba.njit(inline="always")
def _cover(y, d, period):
    """Strip length in ``[0, y]``, strips ``[k P, k P + d)``."""
    k = math.floor(y / period)
    return k * d + min(y - k * period, d)


@numba.njit
def grid_transmission(mus, mui, t, s, d, period, h):
    """The grid's Day & Dance period mean (:func:`xray_viz.physics.grid.period_mean`, the
    same formula on scalars): attenuations in 1/mm, ``t`` across and ``s`` along the strips."""
    length = h * math.sqrt(1.0 + t * t + s * s)
    p = h * abs(t)
    base = math.exp(-mui * length)
    k = (mus - mui) * length
    if p <= 1e-12 * period:
        return base * ((period - d) + d * math.exp(-k)) / period
    x0, x1 = 0.0, d
    x2 = (-p) % period
    x3 = (d - p) % period
    # sort the four kinks (a small network)
    if x0 > x1:
        x0, x1 = x1, x0
    if x2 > x3:
        x2, x3 = x3, x2
    if x0 > x2:
        x0, x2 = x2, x0
    if x1 > x3:
        x1, x3 = x3, x1
    if x1 > x2:
        x1, x2 = x2, x1
    total = 0.0
    prev = x0
    fp = min(max((_cover(prev + p, d, period) - _cover(prev, d, period)) / p, 0.0), 1.0)
    for i in range(4):
        nxt = x1 if i == 0 else (x2 if i == 1 else (x3 if i == 2 else period))
        fn = min(max((_cover(nxt + p, d, period) - _cover(nxt, d, period)) / p, 0.0), 1.0)
        total += (nxt - prev) * _seg(k, fp, fn)
        prev = nxt
        fp = fn
    return base * total / period


@numba.njit(inline="always")
def _reading(e, d, a, fa, resp, gpar):
    """A photon's score in the detector images: ``q(e)`` (the response table, linear in
    energy) times the grid's transmission at its angle (``gpar[0] > 0``)."""
    x = e / gpar[5]
    i = min(int(x), resp.shape[1] - 2)
    f = x - i
    q = resp[0, i] * (1.0 - f) + resp[0, i + 1] * f
    if gpar[0] <= 0.0:
        return q
    dn = abs(d[0] * fa[16] + d[1] * fa[17] + d[2] * fa[18])
    tx = (d[0] * fa[10] + d[1] * fa[11] + d[2] * fa[12]) / dn
    ty = (d[0] * fa[13] + d[1] * fa[14] + d[2] * fa[15]) / dn
    mus = resp[1, i] * (1.0 - f) + resp[1, i + 1] * f
    mui = resp[2, i] * (1.0 - f) + resp[2, i + 1] * f
    return q * grid_transmission(mus, mui, tx - a / gpar[4], ty, gpar[1], gpar[2], gpar[3])


@numba.njit(cache=True, nogil=True)
def run_batch(n_hist, state, emission, world, bvh, rank_order, volumes, tracks, tables,
              scores, reading):
    """Run ``n_hist`` histories with the random stream ``state``; add into the tallies.

    The arguments after ``state``, each a named tuple (the kernel unpacks them into the names
    used below): ``emission`` :class:`Emission` ``(fa, energies, cdf)``, where photons start
    and their spectrum (:mod:`xray_viz.montecarlo.sources`); ``world`` ``(world_lo,
    world_hi)``, the world's box; ``bvh`` the bodies' triangles
    (:class:`~xray_viz.montecarlo.geometry.BVH`) and ``rank_order`` the bodies by decreasing
    precedence; ``volumes`` :class:`Volumes`; ``tracks`` :class:`Tracks`; ``tables``
    :class:`Tables`, the regions' interaction data; ``scores`` :class:`Scores` ``(dep, img,
    img_sq, totals)``; ``reading`` ``(resp, gpar)``, the detector's reading.

    ``dep`` (2, R): energy per region (0: the world, 1 + b: body b) summed over histories and
    its per-history squares; ``img``, ``img_sq`` (4, H, W): primary, single incoherent,
    single coherent, multiple; ``totals`` (``TOTALS``). Energies in keV.

    Voxel volumes (``V`` of them; ``V = 0``: none, the loop is the meshes' alone): ``vol_inv``
    (V, 3, 4) world-to-index affines, ``vol_dims`` (V, 3), the grids' classes and weights
    flattened one after the other (``vol_start`` (V,) where each begins), ``vol_region0``
    (V,): region (row of ``mu``) of class ``c`` is ``vol_region0[v] + c``; ``vol_displace``
    (V, B) the mesh bodies that replace the volume's material where they are; ``vol_maj``
    (V, 3, N) the majorant of the volume's voxels (row 0; ``max over classes of the largest
    weight x mu``). Woodcock tracking in the grids' boxes: flights with the meshes' ``mu``
    plus the majorants, a collision real with probability ``mu(point) / mu_max``.

    Tracks: the first ``trk_n.shape[0]`` histories write their vertices (the start, each
    real interaction, the end) in ``trk_xyz`` (n, K, 3), their count in ``trk_n`` and what
    ended them in ``trk_end`` (:data:`TRACK_ENDS`). Nothing else depends on them.

    The detector's reading: with ``gpar[0] < 0`` each photon scores its energy ``e`` in the
    images; otherwise ``q(e)``, ``resp[0]`` on the energies ``0, gpar[5], 2 gpar[5], ...``
    (the response and the scintillator), times, with ``gpar[0] > 0``, the anti-scatter grid's
    transmission (``resp[1]``, ``resp[2]``: strip and interspace attenuation, 1/mm; ``gpar[1:5]``:
    strip thickness, period, height and focus distance, mm; strips along ``ve``, the angle
    across them from the focused direction at the photon's point). The energy balance
    (``totals``) is always the energy.
    """
    fa, energies, cdf = emission
    world_lo, world_hi = world
    (vol_inv, vol_dims, vol_start, vol_classes, vol_weights, vol_region0, vol_displace,
     vol_maj) = volumes
    trk_xyz, trk_n, trk_end = tracks
    mu, ln_e0, d_ln_e, sf, cum, dx = tables
    dep, img, img_sq, totals = scores
    resp, gpar = reading
    n_bodies = rank_order.shape[0]
    n_reg = dep.shape[1]                  # the world, the bodies, the volumes' classes
    h_img = img.shape[1]
    w_img = img.shape[2]
    inside = np.zeros(max(n_bodies, 1), np.int64)
    hist = np.zeros(n_reg)
    stack = np.empty(128, np.int64)
    tie_body = np.empty(16, np.int64)
    tie_enter = np.empty(16, np.bool_)
    o = np.empty(3)
    d = np.empty(3)
    n_vol = vol_dims.shape[0]
    in_vol = np.zeros(max(n_vol, 1), np.bool_)
    n_trk = trk_n.shape[0]
    for h in range(n_hist):
        sample_direction(fa, state, o, d)
        e = sample_energy(energies, cdf, state)
        if h < n_trk:
            trk_n[h] = 0
            _track(trk_xyz, trk_n, h, o[0], o[1], o[2])
        totals[0] += e
        inside[:] = 0
        region = -1
        n_incoh = 0
        n_coh = 0
        t_cur = 0.0
        plane_passed = False                  # this flight crossed the plane outside it
        to_detector = 0.0
        escaped = 0.0
        alive = True
        while alive:
            m = region + 1
            mus = mu_lookup(mu[m], ln_e0, d_ln_e, e)
            mut = mus[0] + mus[1] + mus[2]
            maj = mut
            t_grid = np.inf                   # the next face of a voxel grid's box
            for v in range(n_vol):
                g0, g1 = _grid_span(o, d, vol_inv[v], vol_dims[v])
                in_vol[v] = g0 <= t_cur and t_cur < g1
                if in_vol[v]:
                    maj += mu_lookup(vol_maj[v], ln_e0, d_ln_e, e)[0]
                    t_grid = min(t_grid, g1)
                elif t_cur < g0 and g0 < g1:
                    t_grid = min(t_grid, g0)
            s = -math.log(1.0 - uniform(state)) / maj if maj > 0.0 else np.inf
            t_int = t_cur + s
            t_exit = _box_exit(o, d, world_lo, world_hi)
            t_limit = min(t_int, t_exit, t_grid)
            # the detector plane, crossed within its rectangle
            t_det = np.inf
            den = d[0] * fa[16] + d[1] * fa[17] + d[2] * fa[18]
            if den != 0.0:
                td = ((fa[7] - o[0]) * fa[16] + (fa[8] - o[1]) * fa[17]
                      + (fa[9] - o[2]) * fa[18]) / den
                # at t_cur itself too (a body's face in the plane: its crossing came first),
                # unless this flight already passed the plane there, outside the rectangle
                if (td > t_cur or (td == t_cur and not plane_passed)) and td <= t_limit:
                    t_det = td
            t_surf, n_ties = next_crossing(o, d, t_cur, min(t_limit, t_det), bvh, stack,
                                           tie_body, tie_enter)
            if t_surf < np.inf and t_surf <= t_det:
                for k in range(n_ties):
                    inside[tie_body[k]] += 1 if tie_enter[k] else -1
                region = region_of(inside, rank_order)
                t_cur = t_surf
                continue
            if t_det < np.inf:
                rx = o[0] + t_det * d[0] - fa[7]
                ry = o[1] + t_det * d[1] - fa[8]
                rz = o[2] + t_det * d[2] - fa[9]
                a = rx * fa[10] + ry * fa[11] + rz * fa[12]
                b = rx * fa[13] + ry * fa[14] + rz * fa[15]
                if abs(a) <= fa[19] and abs(b) <= fa[20]:
                    col = min(int((a + fa[19]) / fa[21]), w_img - 1)
                    row = min(int((fa[20] - b) / fa[22]), h_img - 1)
                    n_int = n_incoh + n_coh
                    cat = 0 if n_int == 0 else (3 if n_int > 1 else (1 if n_incoh else 2))
                    if gpar[0] < 0.0:
                        img[cat, row, col] += e
                        img_sq[cat, row, col] += e * e
                    else:
                        score = _reading(e, d, a, fa, resp, gpar)
                        img[cat, row, col] += score
                        img_sq[cat, row, col] += score * score
                    to_detector = e
                    if h < n_trk:
                        _track(trk_xyz, trk_n, h, o[0] + t_det * d[0], o[1] + t_det * d[1],
                               o[2] + t_det * d[2])
                        trk_end[h] = 0 if n_int == 0 else 1
                    alive = False
                    break
                # past the plane outside the rectangle: fly on from there
                t_cur = t_det
                plane_passed = True
                continue
            if t_grid < t_int and t_grid < t_exit:
                t_cur = t_grid                # into or out of a grid: a new flight from there
                continue
            if t_int >= t_exit:
                escaped = e
                if h < n_trk:
                    _track(trk_xyz, trk_n, h, o[0] + t_exit * d[0], o[1] + t_exit * d[1],
                           o[2] + t_exit * d[2])
                    trk_end[h] = 2
                alive = False
                break
            r = uniform(state) * maj
            kind = 0
            if maj == mut:                    # the meshes' material alone
                kind = 0 if r < mus[0] else (1 if r < mus[0] + mus[1] else 2)
            else:
                # a tentative collision in a grid: each grid's voxel (unless a mesh that
                # displaces it is here), then the meshes' material, else a virtual one
                x = o[0] + t_int * d[0]
                y = o[1] + t_int * d[1]
                z = o[2] + t_int * d[2]
                acc = 0.0
                hit = -1
                world_here = region < 0
                for v in range(n_vol):
                    if not in_vol[v] or hit >= 0:
                        continue
                    shut = False
                    for b in range(n_bodies):
                        if inside[b] > 0 and vol_displace[v, b]:
                            shut = True
                    if shut:
                        continue
                    q = vol_start[v] + _voxel(x, y, z, vol_inv[v], vol_dims[v])
                    c = vol_classes[q]
                    if c == 0:
                        continue
                    world_here = False
                    vm = vol_region0[v] + c
                    wv = vol_weights[q]
                    vmu = mu_lookup(mu[vm], ln_e0, d_ln_e, e)
                    if r < acc + wv * vmu[0]:
                        hit, kind = vm, 0
                    elif r < acc + wv * (vmu[0] + vmu[1]):
                        hit, kind = vm, 1
                    elif r < acc + wv * (vmu[0] + vmu[1] + vmu[2]):
                        hit, kind = vm, 2
                    acc += wv * (vmu[0] + vmu[1] + vmu[2])
                if hit < 0 and (region >= 0 or world_here):
                    # the meshes' material (a tank around the volume adds to its voxels), or
                    # the world medium where no voxel of a class replaces it
                    if r < acc + mus[0]:
                        hit, kind = m, 0
                    elif r < acc + mus[0] + mus[1]:
                        hit, kind = m, 1
                    elif r < acc + mut:
                        hit, kind = m, 2
                if hit < 0:                   # a virtual collision: fly on, unchanged
                    t_cur = t_int
                    continue
                m = hit
            # an interaction at t_int: a new flight from there
            for k in range(3):
                o[k] = o[k] + t_int * d[k]
            t_cur = 0.0
            plane_passed = False
            if h < n_trk:
                _track(trk_xyz, trk_n, h, o[0], o[1], o[2])
            if kind == 0:
                hist[m] += e
                if h < n_trk:
                    trk_end[h] = 3
                alive = False
                break
            if kind == 1:
                cost, e2 = sample_incoherent(e, sf[m], dx, state)
                hist[m] += e - e2
                e = e2
                n_incoh += 1
            else:
                cost = sample_coherent(e, cum[m], dx, state)
                n_coh += 1
            _rotate(d, cost, 2.0 * math.pi * uniform(state))
            if e < CUTOFF_KEV:
                hist[m] += e
                if h < n_trk:
                    trk_end[h] = 3
                alive = False
                break
        totals[1] += to_detector
        totals[2] += to_detector * to_detector
        totals[3] += escaped
        in_bodies = 0.0
        for k in range(n_reg):
            if hist[k] != 0.0:
                dep[0, k] += hist[k]
                dep[1, k] += hist[k] * hist[k]
                totals[4] += hist[k]
                if k > 0:
                    in_bodies += hist[k]
                hist[k] = 0.0
        totals[5] += 1.0
        totals[6] += in_bodies * in_bodies
