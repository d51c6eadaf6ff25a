"""The numba kernel of :mod:`xray_viz.gradients`: one pass over a body's triangles.

Each triangle is projected onto the detector grid (through the source for a point source,
along the beam for a parallel one), the pixel centres it covers are found by edge functions
(pixel centres on an edge go to one side by a top-left rule), and for each covered pixel the
hit's ``t`` on the triangle's plane along that pixel's own ray gives the hit's contribution
``slope * [n, (p - c) x n] / (n . d)`` (see :mod:`xray_viz.gradients`) to the six pose
derivatives of that pixel. The slope of an entry is ``-g`` and of an exit ``+g`` (``g``: the
ray's ``d ell / d L`` of the body), which is the sweep's derivative when no other body's
material surrounds the hit: :mod:`xray_viz.gradients` uses this kernel only for bodies whose
bounding boxes meet no other body's.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from xray_viz.tracing import _numba_cache  # noqa: F401  (where the kernels below are cached)

__all__ = ["project_to_grid", "body_pose_gradient", "volume_centroid"]


def project_to_grid(points, ends, w, *, source=None, direction=None):
    """Image coordinates ``(col, row)`` (pixel centres at integers) of 3D points.

    Parameters
    ----------
    points : (n, 3) float
    ends : (W * H, 3) float
        Where each ray meets the detector (:attr:`xray_viz.geometry.Rays.ends`), image order.
    w : int
        Image width.
    source : (3,) float, optional
        The point source (else ``direction``: a parallel beam).

    Returns
    -------
    (n, 2) float, (n,) bool
        The coordinates, and whether each point is in front of the source.
    """
    p00 = ends[0]
    eu = ends[1] - p00
    ev = ends[w] - p00
    normal = np.cross(eu, ev)
    x = np.asarray(points, dtype=np.float64)
    if source is not None:
        rel = x - source
        den = rel @ normal
        front = den > 0 if (p00 - source) @ normal > 0 else den < 0
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = ((p00 - source) @ normal) / den
        q = source + lam[:, None] * rel
    else:
        mu = ((p00 - x) @ normal) / (direction @ normal)
        q = x + mu[:, None] * direction
        front = np.ones(len(x), bool)
    axes = np.stack([eu, ev], axis=1)                                   # (3, 2)
    cr = ((q - p00) @ axes) @ np.linalg.inv(axes.T @ axes).T
    return cr, front & np.all(np.isfinite(cr), axis=1)


@njit(cache=True, nogil=True, error_model="numpy")
def _inside(e, dx, dy):
    """Edge function ``e`` of an edge running ``(dx, dy)`` (counter-clockwise order): inside,
    or on it and the edge is a top or left one."""
    if e > 0.0:
        return True
    if e < 0.0:
        return False
    return dy < 0.0 or (dy == 0.0 and dx > 0.0)


@njit(cache=True, nogil=True, error_model="numpy")
def body_pose_gradient(vertices, faces, cr, front, origins, directions, t_max, g, center, w, h,
                       out):
    """Add each covered pixel's hits on the triangles ``faces`` to ``out`` (6, W * H).

    ``origins`` is (1, 3) for a point source (all rays from it) or (W * H, 3); ``g`` is
    (W * H,) ``d ell / d L`` of this body per ray.
    """
    one_origin = origins.shape[0] == 1
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
                o = origins[0] if one_origin else origins[k]
                dx, dy, dz = directions[k, 0], directions[k, 1], directions[k, 2]
                nd = nx * dx + ny * dy + nz * dz
                if nd == 0.0:
                    continue
                t = (nx * (v0[0] - o[0]) + ny * (v0[1] - o[1]) + nz * (v0[2] - o[2])) / nd
                if t < 0.0 or t > t_max[k]:
                    continue
                coef = (g[k] if nd > 0.0 else -g[k]) / nd     # exits +g, entries -g
                qx = o[0] + t * dx - center[0]
                qy = o[1] + t * dy - center[1]
                qz = o[2] + t * dz - center[2]
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
