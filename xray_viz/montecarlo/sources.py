"""Where the photons start: the scene's source emitting into the field its detector covers.

A point source emits isotropically (uniform per unit solid angle) into the rectangle the
detector's pixels cover (edges of the outer pixels: ``W x pitch`` by ``H x pitch`` around
the grid's middle, offset and tilted detectors included); a parallel beam starts its photons
uniformly over that rectangle, one source-to-detector distance upstream. One history is one
photon emitted into the field. Energies from the scene's spectrum (the one the primary render
uses: :func:`xray_viz.physics.spectra.source_spectrum`), taken as they are listed.
"""

from __future__ import annotations

import math

import numba
import numpy as np

import xray_viz.tracing._numba_cache  # noqa: F401  (the kernels' one disk cache)

from xray_viz.montecarlo.rng import uniform

__all__ = ["field", "solid_angle", "rectangle_solid_angle", "pixel_shares", "FIELD_SIZE"]  # and two kernels

#: Entries of the array :func:`field` returns.
FIELD_SIZE = 24


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def field(acquisition) -> np.ndarray:
    """The field as the kernels read it: (FIELD_SIZE,) float.

    ``[0:3]`` source, ``[3:6]`` axis (to the field's middle), ``[6]`` cos of the widest angle
    from it, ``[7:10]`` middle, ``[10:13]`` ho, ``[13:16]`` ve, ``[16:19]`` normal, ``[19]``,
    ``[20]`` half widths, ``[21]``, ``[22]`` pitches, ``[23]`` 1 for a parallel beam.
    """
    f = acquisition.frame
    (w, h), (pu, pv) = f.shape, f.pitch
    hu, hv = 0.5 * w * pu, 0.5 * h * pv
    middle = np.asarray(f.middle, float)
    src = np.asarray(f.source, float)
    axis = _unit(middle - src) if not f.parallel else np.asarray(f.forward, float)
    corners = [middle + a * hu * f.ho + b * hv * f.ve for a in (-1, 1) for b in (-1, 1)]
    cos_max = min(float(_unit(c - src) @ axis) for c in corners)
    out = np.zeros(FIELD_SIZE)
    out[0:3], out[3:6], out[6] = src, axis, cos_max
    out[7:10], out[10:13], out[13:16], out[16:19] = middle, f.ho, f.ve, f.normal
    out[19], out[20], out[21], out[22] = hu, hv, pu, pv
    out[23] = 1.0 if f.parallel else 0.0
    if f.parallel:
        out[0:3] = middle - f.sid * np.asarray(f.forward, float)
    return out


def rectangle_solid_angle(point, middle, u, v, half_u, half_v) -> float:
    """Solid angle (sr) of the rectangle ``middle +- half_u u +- half_v v`` seen from
    ``point``: two triangles by Van Oosterom and Strackee's formula.

    Examples
    --------
    >>> z = np.zeros(3); ex, ey = np.eye(3)[0], np.eye(3)[1]
    >>> omega = rectangle_solid_angle(z, np.array([0, 0, 1.0]), ex, ey, 1.0, 1.0)
    >>> bool(np.isclose(omega, 4 * np.pi / 6))          # a face of a cube from its centre
    True
    """
    return float(_rectangles(np.asarray(point, float), np.asarray(middle, float)[None, :],
                             np.asarray(u, float), np.asarray(v, float), half_u, half_v)[0])


def _rectangles(point, middles, u, v, half_u, half_v) -> np.ndarray:
    """:func:`rectangle_solid_angle` of the rectangles centred at ``middles`` (N, 3)."""
    c = [middles + (a * half_u) * u + (b * half_v) * v - point
         for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    n = [np.linalg.norm(r, axis=-1) for r in c]

    def dot(i, j):
        return np.einsum("...k,...k->...", c[i], c[j])

    def tri(i, j, k):
        num = np.einsum("...k,...k->...", c[i], np.cross(c[j], c[k]))
        den = n[i] * n[j] * n[k] + dot(i, j) * n[k] + dot(i, k) * n[j] + dot(j, k) * n[i]
        return 2.0 * np.arctan2(np.abs(num), den)

    return tri(0, 1, 2) + tri(0, 2, 3)


def pixel_shares(acquisition) -> np.ndarray:
    """(H, W): each pixel's share of the photons emitted into the field, in vacuum (the
    transport's histories per pixel): its solid angle over the field's for a point source,
    its area over the field's for a parallel beam. Sums to 1.

    Examples
    --------
    >>> import xray_viz
    >>> share = pixel_shares(xray_viz.load_scene("sphere").acquisition)
    >>> share.shape, round(float(share.sum()), 12), bool(share[128, 128] > share[0, 0])
    ((256, 256), 1.0, True)
    """
    f = acquisition.frame
    (w, h), (pu, pv) = f.shape, f.pitch
    if f.parallel:
        return np.full((h, w), 1.0 / (w * h))
    cols = (np.arange(w) + 0.5) - w / 2
    rows = h / 2 - (np.arange(h) + 0.5)
    ho, ve = np.asarray(f.ho, float), np.asarray(f.ve, float)
    middles = (np.asarray(f.middle, float)[None, None, :] + (cols * pu)[None, :, None] * ho
               + (rows * pv)[:, None, None] * ve)
    omega = _rectangles(np.asarray(f.source, float), middles, ho, ve, pu / 2, pv / 2)
    return omega / solid_angle(acquisition)


def solid_angle(acquisition) -> float:
    """Solid angle (sr) of the field seen from a point source (:func:`rectangle_solid_angle`).

    Examples
    --------
    >>> import xray_viz
    >>> acq = xray_viz.load_scene("sphere").acquisition
    >>> 0 < solid_angle(acq) < 2 * np.pi
    True
    """
    fa = field(acquisition)
    return rectangle_solid_angle(fa[0:3], fa[7:10], fa[10:13], fa[13:16], fa[19], fa[20])


@numba.njit(cache=True, nogil=True)
def sample_direction(fa, state, origin, direction):
    """A photon's start into the field ``fa`` (:func:`field`): ``origin`` and ``direction``
    filled in place. A point source: directions uniform in the cone around the axis that
    holds the rectangle, kept where they meet it."""
    if fa[23] > 0.0:                          # parallel beam
        a = (2.0 * uniform(state) - 1.0) * fa[19]
        b = (2.0 * uniform(state) - 1.0) * fa[20]
        for k in range(3):
            origin[k] = fa[k] + a * fa[10 + k] + b * fa[13 + k]
            direction[k] = fa[3 + k]
        return
    ax, ay, az = fa[3], fa[4], fa[5]
    # an orthonormal pair across the axis
    if abs(ax) < 0.9:
        px, py, pz = 0.0, az, -ay
    else:
        px, py, pz = -az, 0.0, ax
    nrm = math.sqrt(px * px + py * py + pz * pz)
    px, py, pz = px / nrm, py / nrm, pz / nrm
    qx, qy, qz = ay * pz - az * py, az * px - ax * pz, ax * py - ay * px
    for k in range(3):
        origin[k] = fa[k]
    while True:
        cost = 1.0 - uniform(state) * (1.0 - fa[6])
        sint = math.sqrt(max(0.0, 1.0 - cost * cost))
        phi = 2.0 * math.pi * uniform(state)
        cp, sp = math.cos(phi) * sint, math.sin(phi) * sint
        dx = cost * ax + cp * px + sp * qx
        dy = cost * ay + cp * py + sp * qy
        dz = cost * az + cp * pz + sp * qz
        den = dx * fa[16] + dy * fa[17] + dz * fa[18]
        if den <= 0.0:
            continue
        t = ((fa[7] - fa[0]) * fa[16] + (fa[8] - fa[1]) * fa[17]
             + (fa[9] - fa[2]) * fa[18]) / den
        rx = fa[0] + t * dx - fa[7]
        ry = fa[1] + t * dy - fa[8]
        rz = fa[2] + t * dz - fa[9]
        if (abs(rx * fa[10] + ry * fa[11] + rz * fa[12]) <= fa[19]
                and abs(rx * fa[13] + ry * fa[14] + rz * fa[15]) <= fa[20]):
            direction[0] = dx
            direction[1] = dy
            direction[2] = dz
            return


@numba.njit(cache=True, nogil=True)
def sample_energy(energies, cdf, state):
    """An energy (keV) of the spectrum: ``cdf`` its cumulative weights (last = 1)."""
    if energies.shape[0] == 1:
        return energies[0]
    r = uniform(state)
    lo = 0
    hi = cdf.shape[0] - 1
    while lo < hi:                             # first k with cdf[k] > r
        mid = (lo + hi) >> 1
        if cdf[mid] > r:
            hi = mid
        else:
            lo = mid + 1
    return energies[lo]
