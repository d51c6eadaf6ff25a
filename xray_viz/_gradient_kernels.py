"""The numba kernel of :mod:`xray_viz.gradients`: one pass over a body's triangles.

Each triangle is projected onto the detector grid (through the source for a point source,
along the beam for a parallel one), the pixel centres it covers are found by edge functions
(pixel centres on an edge go to one side by a top-left rule), and for each covered pixel the
hit's ``t`` on the triangle's plane along that pixel's own ray (made from the pixel's point
on the detector, as :func:`xray_viz.geometry.detector_rays` makes it) gives the hit's
contribution
``slope * [n, (p - c) x n] / (n . d)`` (see :mod:`xray_viz.gradients`) to the six pose
derivatives of that pixel. The slope of an entry is ``-g`` and of an exit ``+g`` (``g``: the
ray's ``d ell / d L`` of the body), which is the sweep's derivative when no other body's
material surrounds the hit: :mod:`xray_viz.gradients` uses this kernel only for bodies whose
bounding boxes meet no other body's.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from xray_viz.tracing import _numba_cache  # noqa: F401  (where the kernels below are cached)
from xray_viz.tracing._primitives import tie_positive

__all__ = ["body_pose_gradient", "volume_centroid", "PixelGrid"]


class PixelGrid(NamedTuple):
    """The detector's pixels and their rays, as :func:`body_pose_gradient` takes them: pixel
    ``(col, row)`` at ``p00 + col eu + row ev``, its ray from ``source`` (a point source) or
    along ``direction`` from ``depth`` mm before it (a parallel beam)."""

    #: ``(3,) float64``: pixel (0, 0).
    p00: np.ndarray
    #: ``(3,) float64``: one pixel along a row.
    eu: np.ndarray
    #: ``(3,) float64``: one pixel down a column.
    ev: np.ndarray
    #: ``(2, 2) float64``: the inverse Gram matrix of ``eu``, ``ev``.
    inv: np.ndarray
    #: ``(3,) float64``: the point source.
    source: np.ndarray
    #: ``(3,) float64``: a parallel beam's direction.
    direction: np.ndarray
    #: A parallel ray's length (mm) before its pixel.
    depth: float
    #: A parallel beam (True) or a point source.
    parallel: bool
    #: Pixels across.
    w: int
    #: Pixels down.
    h: int


@njit(cache=True, nogil=True, error_model="numpy")
def _inside(e, dx, dy):
    """Edge function ``e`` of an edge running ``(dx, dy)`` (counter-clockwise order): inside,
    or on it and the tie rule gives it to this side (``xray_viz.tracing._primitives``)."""
    if e > 0.0:
        return True
    if e < 0.0:
        return False
    return tie_positive(dx, dy)


@njit(cache=True, nogil=True, error_model="numpy")
def _project(vertices, p00, inv, eu, ev, source, direction, parallel, cr, front):
    """Each vertex's image coordinates ``(col, row)`` (``cr``) and whether it is in front of
    the source (``front``): the line through it from the source (or along the beam) meets the
    detector plane ``p00 + col eu + row ev``; ``inv`` is the inverse Gram matrix of eu, ev."""
    nx = eu[1] * ev[2] - eu[2] * ev[1]
    ny = eu[2] * ev[0] - eu[0] * ev[2]
    nz = eu[0] * ev[1] - eu[1] * ev[0]
    plane = nx * (p00[0] - source[0]) + ny * (p00[1] - source[1]) + nz * (p00[2] - source[2])
    dn = nx * direction[0] + ny * direction[1] + nz * direction[2]
    for i in range(vertices.shape[0]):
        x0, x1, x2 = vertices[i, 0], vertices[i, 1], vertices[i, 2]
        if parallel:
            mu = (nx * (p00[0] - x0) + ny * (p00[1] - x1) + nz * (p00[2] - x2)) / dn
            q0, q1, q2 = x0 + mu * direction[0], x1 + mu * direction[1], x2 + mu * direction[2]
            front[i] = True
        else:
            r0, r1, r2 = x0 - source[0], x1 - source[1], x2 - source[2]
            den = nx * r0 + ny * r1 + nz * r2
            front[i] = den * plane > 0.0
            if not front[i]:
                continue
            lam = plane / den
            q0, q1, q2 = source[0] + lam * r0, source[1] + lam * r1, source[2] + lam * r2
        q0 -= p00[0]
        q1 -= p00[1]
        q2 -= p00[2]
        a = q0 * eu[0] + q1 * eu[1] + q2 * eu[2]
        b = q0 * ev[0] + q1 * ev[1] + q2 * ev[2]
        cr[i, 0] = inv[0, 0] * a + inv[0, 1] * b
        cr[i, 1] = inv[1, 0] * a + inv[1, 1] * b


@njit(cache=True, nogil=True, error_model="numpy")
def body_pose_gradient(vertices, faces, center, pixels, g, out):
    """Add each covered pixel's hits on the triangles ``faces`` to ``out`` (6, W * H).

    Pixel ``(col, row)`` lies at ``p00 + col eu + row ev`` on the detector; its ray comes from
    ``source`` (a point source) or runs along ``direction`` from ``depth`` mm before it (a
    parallel beam), as :func:`xray_viz.geometry.detector_rays` makes them (``pixels``, a
    :class:`PixelGrid`). ``g`` is (W * H,) ``d ell / d L`` of this body per ray.
    """
    p00, eu, ev, inv, source, direction, depth, parallel, w, h = pixels
    nv = vertices.shape[0]
    cr = np.empty((nv, 2))
    front = np.empty(nv, np.bool_)
    _project(vertices, p00, inv, eu, ev, source, direction, parallel, cr, front)
    for f in range(faces.shape[0]):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        if not (front[i0] and front[i1] and front[i2]):
            continue
        ax, ay = cr[i0, 0], cr[i0, 1]
        bx, by = cr[i1, 0], cr[i1, 1]
        cx, cy = cr[i2, 0], cr[i2, 1]
        area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        if area == 0.0:
            continue
        if area < 0.0:                     # order the projected corners one way
            bx, by, cx, cy = cx, cy, bx, by
        c0 = max(0, int(np.ceil(min(ax, bx, cx))))
        c1 = min(w - 1, int(np.floor(max(ax, bx, cx))))
        r0 = max(0, int(np.ceil(min(ay, by, cy))))
        r1 = min(h - 1, int(np.floor(max(ay, by, cy))))
        if c0 > c1 or r0 > r1:
            continue
        v0 = vertices[i0]
        e1 = vertices[i1] - v0
        e2 = vertices[i2] - v0
        nx = e1[1] * e2[2] - e1[2] * e2[1]
        ny = e1[2] * e2[0] - e1[0] * e2[2]
        nz = e1[0] * e2[1] - e1[1] * e2[0]
        for r in range(r0, r1 + 1):
            for c in range(c0, c1 + 1):
                px, py = float(c), float(r)
                if not (_inside((bx - ax) * (py - ay) - (by - ay) * (px - ax), bx - ax, by - ay)
                        and _inside((cx - bx) * (py - by) - (cy - by) * (px - bx), cx - bx,
                                    cy - by)
                        and _inside((ax - cx) * (py - cy) - (ay - cy) * (px - cx), ax - cx,
                                    ay - cy)):
                    continue
                k = r * w + c
                if g[k] == 0.0:
                    continue
                # the pixel's point on the detector, and its ray
                e0 = p00[0] + c * eu[0] + r * ev[0]
                e1_ = p00[1] + c * eu[1] + r * ev[1]
                e2_ = p00[2] + c * eu[2] + r * ev[2]
                if parallel:
                    dx, dy, dz = direction[0], direction[1], direction[2]
                    t_max = depth
                    ox, oy, oz = e0 - depth * dx, e1_ - depth * dy, e2_ - depth * dz
                else:
                    ox, oy, oz = source[0], source[1], source[2]
                    dx, dy, dz = e0 - ox, e1_ - oy, e2_ - oz
                    t_max = np.sqrt(dx * dx + dy * dy + dz * dz)
                    dx, dy, dz = dx / t_max, dy / t_max, dz / t_max
                nd = nx * dx + ny * dy + nz * dz
                if nd == 0.0:
                    continue
                t = (nx * (v0[0] - ox) + ny * (v0[1] - oy) + nz * (v0[2] - oz)) / nd
                if t < 0.0 or t > t_max:
                    continue
                coef = (g[k] if nd > 0.0 else -g[k]) / nd     # exits +g, entries -g
                qx = ox + t * dx - center[0]
                qy = oy + t * dy - center[1]
                qz = oz + t * dz - center[2]
                out[0, k] += coef * nx
                out[1, k] += coef * ny
                out[2, k] += coef * nz
                out[3, k] += coef * (qy * nz - qz * ny)
                out[4, k] += coef * (qz * nx - qx * nz)
                out[5, k] += coef * (qx * ny - qy * nx)


@njit(cache=True, nogil=True, error_model="numpy")
def volume_centroid(vertices, faces, ref):
    """The volume centroid of a closed surface: signed tetrahedra from ``ref``; ``ref``
    itself when the volume is 0."""
    total = 0.0
    sx = sy = sz = 0.0
    for f in range(faces.shape[0]):
        a = vertices[faces[f, 0]] - ref
        b = vertices[faces[f, 1]] - ref
        c = vertices[faces[f, 2]] - ref
        vol = (a[0] * (b[1] * c[2] - b[2] * c[1]) + a[1] * (b[2] * c[0] - b[0] * c[2])
               + a[2] * (b[0] * c[1] - b[1] * c[0]))
        total += vol
        sx += vol * (a[0] + b[0] + c[0])
        sy += vol * (a[1] + b[1] + c[1])
        sz += vol * (a[2] + b[2] + c[2])
    out = ref.copy()
    if total != 0.0:
        out[0] += sx / (4.0 * total)
        out[1] += sy / (4.0 * total)
        out[2] += sz / (4.0 * total)
    return out


# Each kernel above has one specialisation, compiled on first use (or loaded from numba's
# cache) through :data:`KERNELS` (:mod:`xray_viz.tracing._compile`); inputs typed read-only,
# so that read-only arrays need no copy (a writable one converts).

from numba.core import types as _nt  # noqa: E402

from xray_viz.tracing._compile import KernelSet  # noqa: E402

_F1r = _nt.Array(_nt.float64, 1, "C", readonly=True)
_F2r = _nt.Array(_nt.float64, 2, "C", readonly=True)
_I2r = _nt.Array(_nt.int64, 2, "C", readonly=True)
#: The one signature of each kernel (a :class:`PixelGrid`'s arrays must arrive read-only:
#: numba converts no named tuple; :func:`pixel_grid` makes it so).
SIGNATURES = {
    "body_pose_gradient": (_F2r, _I2r, _F1r, _nt.NamedTuple(
        (_F1r, _F1r, _F1r, _F2r, _F1r, _F1r, _nt.float64, _nt.boolean, _nt.int64, _nt.int64),
        PixelGrid), _F1r, _nt.Array(_nt.float64, 2, "C")),
    "volume_centroid": (_F2r, _I2r, _F1r),
}
#: The kernels above, each compiled for its one signature on first use.
KERNELS = KernelSet(__name__, {"body_pose_gradient": body_pose_gradient,
                               "volume_centroid": volume_centroid}, SIGNATURES)


def _ro(a, dtype=np.float64):
    a = np.ascontiguousarray(a, dtype=dtype).view()
    a.flags.writeable = False
    return a


def pixel_grid(p00, eu, ev, inv, source, direction, depth, parallel, w, h) -> PixelGrid:
    """The :class:`PixelGrid` of these values as :data:`KERNELS` takes it (float64 arrays,
    read-only views: no copy when they already are float64 and C-contiguous)."""
    return PixelGrid(_ro(p00), _ro(eu), _ro(ev), _ro(inv), _ro(source), _ro(direction),
                     float(depth), bool(parallel), int(w), int(h))
