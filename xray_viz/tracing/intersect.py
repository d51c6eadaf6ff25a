"""Ray-triangle intersection: the thesis' Moller-Trumbore test and its watertight form.

Both functions are vectorised over *pairs*: element ``k`` tests ray ``(origins[k],
directions[k])`` against triangle ``(v0[k], v1[k], v2[k])``. A point on a ray is
``r(t) = origin + t * direction`` (Eq. 1.1); a point of the triangle's plane is
``alpha v0 + beta v1 + gamma v2`` with ``alpha + beta + gamma = 1`` (Eq. 1.7-1.8).

:func:`moller_trumbore` is Eq. 1.10-1.17 as the thesis derives them, with Listing 1's bugs
fixed (it multiplied by ``C`` instead of ``1/C`` and used an absolute ``1e-9`` parallel test).
Its edge tests are inclusive, so a ray through an edge shared by two triangles hits both:
a closed surface is crossed twice, and the path length through it is wrong. It is kept for
teaching and as a baseline.

:func:`watertight_intersect` is the test the engine uses (Woop, Benthin and Wald, "Watertight
Ray/Triangle Intersection", JCGT 2013): the vertices are moved into a frame where the ray is
the z axis, and the 2D edge functions are evaluated with their signs made *exact* (an error
bound decides when to recompute a sign in exact rational arithmetic). An edge function that
is exactly zero is resolved by a fixed rule (a symbolic perturbation of the ray), so that a ray
through an edge or a vertex shared by several triangles of one surface crosses it exactly once.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np

__all__ = ["moller_trumbore", "watertight_intersect"]


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def moller_trumbore(origins, directions, v0, v1, v2, *, t_min=0.0, t_max=np.inf,
                    parallel_tolerance=1e-12, listing_bug=False):
    """The thesis' Moller-Trumbore test (Eq. 1.10-1.17), vectorised over ray-triangle pairs.

    Parameters
    ----------
    origins, directions : (n, 3) float
        Rays ``r(t) = origin + t * direction``.
    v0, v1, v2 : (n, 3) float
        Triangle vertices.
    t_min, t_max : float or (n,) float
        Accepted range of ``t``.
    parallel_tolerance : float
        The ray counts as parallel to the plane when ``|C| <= tol * |e1| |e2| |d|``: a test
        relative to the triangle and ray sizes (Listing 1 used an absolute ``1e-9``).
    listing_bug : bool
        Reproduce Listing 1's bug: multiply by ``C`` where ``1 / C`` is meant. For teaching.

    Returns
    -------
    hit : (n,) bool
    t : (n,) float
        Ray parameter of the hit (NaN where there is none).
    beta, gamma : (n,) float
        Barycentric coordinates of the hit point (Eq. 1.13): ``v0 + beta e1 + gamma e2``.

    Examples
    --------
    >>> import numpy as np
    >>> o = np.array([[0.2, 0.2, 1.0]]); d = np.array([[0.0, 0.0, -1.0]])
    >>> tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    >>> hit, t, beta, gamma = moller_trumbore(o, d, tri[:1], tri[1:2], tri[2:])
    >>> bool(hit[0]), float(t[0]), float(beta[0]), float(gamma[0])
    (True, 1.0, 0.2, 0.2)
    """
    o = np.asarray(origins, float)
    d = np.asarray(directions, float)
    e1 = np.asarray(v1, float) - v0                      # Eq. 1.10
    e2 = np.asarray(v2, float) - v0                      # Eq. 1.11
    p = np.cross(d, e2)
    C = _dot(e1, p)
    scale = np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1) * np.linalg.norm(d, axis=1)
    parallel = np.abs(C) <= parallel_tolerance * scale
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = C if listing_bug else 1.0 / C
        tvec = o - v0                                    # r - v0 at t = 0
        beta = _dot(tvec, p) * inv                       # Eq. 1.15
        q = np.cross(tvec, e1)
        gamma = _dot(d, q) * inv                         # Eq. 1.16
        t = _dot(e2, q) * inv                            # Eq. 1.17
        hit = (~parallel & (beta >= 0) & (beta <= 1) & (gamma >= 0) & (beta + gamma <= 1)
               & (t >= t_min) & (t <= t_max))
    return hit, np.where(hit, t, np.nan), beta, gamma


# --- exact signs --------------------------------------------------------------------------

#: A bound on the rounding error of fl(a*b - c*d) relative to |a*b| + |c*d| (a few ulps).
_ERRBOUND = 4.0 * np.finfo(np.float64).eps


def _exact_sign(a, b, c, d, approx):
    """Exact sign of ``a*b - c*d`` for float64 arrays, given the rounded value ``approx``.

    Where the rounded value is farther from zero than its error bound its sign is already
    exact; the rest (rays on or near an edge) are recomputed in rational arithmetic.
    """
    sign = np.sign(approx).astype(np.int8)
    unsure = np.abs(approx) <= _ERRBOUND * (np.abs(a * b) + np.abs(c * d))
    if np.any(unsure):
        idx = np.flatnonzero(unsure)
        exact = [
            Fraction(float(a[k])) * Fraction(float(b[k])) - Fraction(float(c[k])) * Fraction(float(d[k]))
            for k in idx
        ]
        sign[idx] = [(x > 0) - (x < 0) for x in exact]
    return sign


def _tie_sign(ex, ey):
    """Sign (+-1, int8) of an edge function that is exactly zero, after perturbing the ray.

    The ray is moved by ``(-eps, -eps * delta)`` in the 2D ray frame (eps, delta -> 0+). For an
    edge function ``cross(P, Q)`` with edge vector ``e = P - Q`` this gives ``sign(-ey + delta ex)``:
    the tie rule of every kernel, ``xray_viz.tracing._primitives.tie_positive`` (its Python
    function, on arrays). The same edge seen from the neighbouring triangle has ``-e`` and gets
    the opposite sign, so exactly one of the two triangles accepts the ray. Imported here, when
    a sign is zero: the NumPy engine does not import numba otherwise.
    """
    from xray_viz.tracing._primitives import tie_positive

    return np.where(tie_positive.py_func(ex, ey), 1, -1).astype(np.int8)


def watertight_intersect(origins, directions, v0, v1, v2, *, t_min=0.0, t_max=np.inf):
    """Watertight ray-triangle test with exact edge signs, vectorised over pairs.

    A ray that passes through an edge or vertex shared by triangles of one closed surface hits
    exactly one of them; a ray grazing a silhouette edge hits both sides (entering and leaving at
    the same ``t``) or neither, so the path length through the surface is exact either way.
    Degenerate (zero-area) triangles, and triangles seen edge-on, are never hit.

    Parameters
    ----------
    origins, directions : (n, 3) float
        Rays ``r(t) = origin + t * direction``; directions need not be unit vectors.
    v0, v1, v2 : (n, 3) float
        Triangle vertices, counter-clockwise seen from outside (outward normal
        ``(v1 - v0) x (v2 - v0)``).
    t_min, t_max : float or (n,) float
        Accepted range of ``t``.

    Returns
    -------
    hit : (n,) bool
    t : (n,) float
        Ray parameter of the hit (NaN where there is none).
    bary : (n, 3) float
        Barycentric coordinates ``(alpha, beta, gamma)`` of the hit point (Eq. 1.7).
    entering : (n,) bool
        True where the ray enters the surface (``direction . normal < 0``).

    Examples
    --------
    Two triangles sharing the diagonal of a unit square, a ray exactly through the diagonal:

    >>> import numpy as np
    >>> a, b, c, d = np.array([[0., 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    >>> o = np.array([[0.5, 0.5, 1.0]] * 2); dirs = np.array([[0.0, 0, -1]] * 2)
    >>> hit, t, bary, entering = watertight_intersect(o, dirs, np.array([a, a]),
    ...                                               np.array([b, c]), np.array([c, d]))
    >>> int(hit.sum()), bool(entering[hit][0])
    (1, True)
    """
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    n = len(d)
    rows = np.arange(n)
    # Ray frame: z along the largest component of d; swap x and y to keep the handedness.
    kz = np.argmax(np.abs(d), axis=1)
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    dz = d[rows, kz]
    flip = dz < 0
    kx, ky = np.where(flip, ky, kx), np.where(flip, kx, ky)
    with np.errstate(divide="ignore", invalid="ignore"):
        sx = d[rows, kx] / dz
        sy = d[rows, ky] / dz
        sz = 1.0 / dz

    def to_ray_frame(v):
        q = np.asarray(v, dtype=np.float64) - o
        qz = q[rows, kz]
        return q[rows, kx] - sx * qz, q[rows, ky] - sy * qz, sz * qz

    ax, ay, az = to_ray_frame(v0)
    bx, by, bz = to_ray_frame(v1)
    cx, cy, cz = to_ray_frame(v2)
    # 2D edge functions (Woop et al. Eq. 3): U for edge b-c, V for c-a, W for a-b.
    u = cx * by - cy * bx
    v = ax * cy - ay * cx
    w = bx * ay - by * ax
    su = _exact_sign(cx, by, cy, bx, u)
    sv = _exact_sign(ax, cy, ay, cx, v)
    sw = _exact_sign(bx, ay, by, ax, w)
    if not (su.all() and sv.all() and sw.all()):      # a ray exactly on an edge: the tie rule
        su = np.where(su == 0, _tie_sign(cx - bx, cy - by), su)
        sv = np.where(sv == 0, _tie_sign(ax - cx, ay - cy), sv)
        sw = np.where(sw == 0, _tie_sign(bx - ax, by - ay), sw)
    hit = (su == sv) & (sv == sw)

    det = u + v + w
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (u * az + v * bz + w * cz) / det
        bary = np.stack([u, v, w], axis=1) / det[:, None]
    # Where rounding left det at zero on a sliver, fall back to the plane equation.
    bad = hit & ~np.isfinite(t)
    if np.any(bad):
        nrm = np.cross(np.asarray(v1)[bad] - v0[bad], np.asarray(v2)[bad] - v0[bad])
        with np.errstate(divide="ignore", invalid="ignore"):
            t[bad] = _dot(nrm, np.asarray(v0)[bad] - o[bad]) / _dot(nrm, d[bad])
        bary[bad] = 1.0 / 3.0
    hit &= np.isfinite(t) & (t >= t_min) & (t <= t_max)
    bary = np.clip(bary, 0.0, 1.0)
    # su > 0 means the triangle winds clockwise seen along the ray: its outward normal faces
    # the ray (d . n < 0), so the ray enters.
    entering = su > 0
    t = np.where(hit, t, np.nan)
    return hit, t, bary, entering
