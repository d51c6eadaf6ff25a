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

import numba
import numpy as np

import xray_viz.tracing._numba_cache  # noqa: F401  (the kernels' one disk cache)

from xray_viz.montecarlo.geometry import next_crossing, region_of
from xray_viz.montecarlo.physics import CUTOFF_KEV, mu_lookup, sample_coherent, sample_incoherent
from xray_viz.montecarlo.rng import uniform
from xray_viz.montecarlo.sources import sample_direction, sample_energy

__all__ = ["TOTALS"]                  # and the kernel ``run_batch``

#: Entries of a batch's ``totals`` (keV summed over its histories; ``*_sq`` of the per-history
#: values).
TOTALS = ("emitted", "detector", "detector_sq", "escaped", "deposited", "histories",
          "deposited_sq")


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


@numba.njit(cache=True, nogil=True)
def run_batch(n_hist, state, fa, energies, cdf, world_lo, world_hi,
              lo, hi, child, start, count, v0, v1, v2, tri_body, rank_order,
              mu, ln_e0, d_ln_e, sf, cum, dx,
              dep, img, img_sq, totals):
    """Run ``n_hist`` histories with the random stream ``state``; add into the tallies.

    ``dep`` (2, R): energy per region (0: the world, 1 + b: body b) summed over histories and
    its per-history squares; ``img``, ``img_sq`` (4, H, W): primary, single incoherent,
    single coherent, multiple; ``totals`` (``TOTALS``). Energies in keV.
    """
    n_bodies = rank_order.shape[0]
    n_reg = n_bodies + 1
    h_img = img.shape[1]
    w_img = img.shape[2]
    inside = np.zeros(max(n_bodies, 1), np.int64)
    hist = np.zeros(n_reg)
    stack = np.empty(128, np.int64)
    tie_body = np.empty(16, np.int64)
    tie_enter = np.empty(16, np.bool_)
    o = np.empty(3)
    d = np.empty(3)
    for _ in range(n_hist):
        sample_direction(fa, state, o, d)
        e = sample_energy(energies, cdf, state)
        totals[0] += e
        inside[:] = 0
        region = -1
        n_incoh = 0
        n_coh = 0
        t_cur = 0.0
        to_detector = 0.0
        escaped = 0.0
        alive = True
        while alive:
            m = region + 1
            mus = mu_lookup(mu[m], ln_e0, d_ln_e, e)
            mut = mus[0] + mus[1] + mus[2]
            s = -math.log(1.0 - uniform(state)) / mut if mut > 0.0 else np.inf
            t_int = t_cur + s
            t_exit = _box_exit(o, d, world_lo, world_hi)
            t_limit = min(t_int, t_exit)
            # the detector plane, crossed within its rectangle
            t_det = np.inf
            den = d[0] * fa[16] + d[1] * fa[17] + d[2] * fa[18]
            if den != 0.0:
                td = ((fa[7] - o[0]) * fa[16] + (fa[8] - o[1]) * fa[17]
                      + (fa[9] - o[2]) * fa[18]) / den
                if td > t_cur and td <= t_limit:
                    t_det = td
            t_surf, n_ties = next_crossing(o, d, t_cur, min(t_limit, t_det), lo, hi, child,
                                           start, count, v0, v1, v2, tri_body, stack,
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
                    img[cat, row, col] += e
                    img_sq[cat, row, col] += e * e
                    to_detector = e
                    alive = False
                    break
                # past the plane outside the rectangle: fly on from there
                t_cur = t_det
                continue
            if t_int >= t_exit:
                escaped = e
                alive = False
                break
            # an interaction at t_int: a new flight from there
            for k in range(3):
                o[k] = o[k] + t_int * d[k]
            t_cur = 0.0
            r = uniform(state) * mut
            if r < mus[0]:
                hist[m] += e
                alive = False
                break
            if r < mus[0] + mus[1]:
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
