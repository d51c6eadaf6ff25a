"""All hits of a set of rays: flat arrays sorted by (ray, t), trimesh style."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from xray_viz.errors import SceneError
from xray_viz.tracing.candidates import candidate_pairs
from xray_viz.tracing.intersect import watertight_intersect

__all__ = ["Hits", "trace_triangles", "trace_rays", "inside_counts", "PROBE"]

#: A fixed, irrational-looking direction for inside/outside tests (no axis, no diagonal).
PROBE = np.array([0.5377, 0.3141, 0.7826]) / np.linalg.norm([0.5377, 0.3141, 0.7826])


@dataclass(frozen=True)
class Hits:
    """Every intersection of every ray, sorted by ray then by ``t``.

    All attributes are parallel arrays of length ``n_hits``; empty results keep their shapes
    (for example ``point`` is ``(0, 3)``).

    Attributes
    ----------
    ray : (n,) int
        Index of the ray.
    t : (n,) float
        Ray parameter: the hit point is ``origin + t * direction``.
    point : (n, 3) float
        The hit point.
    triangle : (n,) int
        Index of the triangle within its body's mesh (``body.faces[triangle]``).
    body : (n,) int
        Index of the body in ``scene.bodies``.
    barycentric : (n, 3) float
        ``(alpha, beta, gamma)`` of the hit point on the triangle (Eq. 1.7).
    entering : (n,) bool
        True where the ray enters the body, False where it leaves.
    """

    ray: np.ndarray
    t: np.ndarray
    point: np.ndarray
    triangle: np.ndarray
    body: np.ndarray
    barycentric: np.ndarray
    entering: np.ndarray

    def __len__(self) -> int:
        return len(self.ray)

    def for_ray(self, k: int) -> "Hits":
        """The hits of ray ``k`` only, in order of ``t``."""
        lo, hi = np.searchsorted(self.ray, [k, k + 1])
        return Hits(*(getattr(self, f)[lo:hi] for f in self.__dataclass_fields__))


def _points(value, name: str) -> np.ndarray:
    """An (n, 3) float64 array from (n, 3) or (3,) real numbers, or SceneError."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.dtype.kind not in "iuf":
        raise SceneError(f"{name} must be an (n, 3) or (3,) array of numbers, got "
                         f"{'dtype ' + str(arr.dtype) if arr is not None else repr(value)}")
    if arr.shape == (3,):
        arr = arr.reshape(1, 3)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise SceneError(f"{name} must have shape (n, 3) or (3,), got {arr.shape}")
    arr = arr.astype(np.float64, copy=False)
    bad = ~np.all(np.isfinite(arr), axis=1)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise SceneError(f"{name} must be finite: row {k} is {arr[k].tolist()} "
                         f"({int(bad.sum())} such row{'s' if bad.sum() > 1 else ''})")
    return arr


def _check_rays(origins, directions):
    """Validated ``(origins, directions)``, both (n, 3) float64 (read-only broadcast views).

    Either may be a single ray, (3,) or (1, 3), shared by all the other's rays; otherwise
    both must have the same number of rows. Directions must be non-zero, with a length whose
    square float64 holds (between about 1e-154 and 1e154).
    """
    o = _points(origins, "origins")
    d = _points(directions, "directions")
    n = len(d) if len(o) == 1 else len(o)
    if len(d) not in (1, n) or len(o) not in (1, n):
        raise SceneError(f"origins ({len(o)} rays) and directions ({len(d)} rays) must have the "
                         "same number of rows, or one of them be a single (3,) vector for all")
    with np.errstate(over="ignore", under="ignore"):
        sq = np.einsum("ij,ij->i", d, d)
    bad = ~(np.isfinite(sq) & (sq >= np.finfo(np.float64).tiny))
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        what = "zero" if not np.any(d[k]) else "a length whose square float64 cannot hold"
        raise SceneError(f"directions must be non-zero vectors of a representable length: row "
                         f"{k} is {d[k].tolist()} ({what}; {int(bad.sum())} such "
                         f"row{'s' if bad.sum() > 1 else ''}); scale the directions")
    return np.broadcast_to(o, (n, 3)), np.broadcast_to(d, (n, 3))


def _broadcast_range(value, n, name):
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.dtype.kind not in "iuf" or arr.ndim > 1 \
            or (arr.ndim == 1 and len(arr) not in (1, n)):
        raise SceneError(f"{name} must be a number or an array of one number per ray ({n}), "
                         f"got {value!r}" if arr is None or arr.size < 8 else
                         f"{name} must be a number or an array of one number per ray ({n}), "
                         f"got shape {arr.shape}")
    arr = np.broadcast_to(arr.astype(np.float64, copy=False).reshape(-1), (n,))
    if np.any(np.isnan(arr)):
        raise SceneError(f"{name} must not be NaN")
    return arr


def _check_axis(axis):
    if axis is None:
        return None
    a = _points(axis, "axis")
    if a.shape != (1, 3) or not np.any(a):
        raise SceneError(f"axis must be one non-zero (3,) vector, got {np.asarray(axis).tolist()}")
    return a[0]


def trace_triangles(triangles, origins, directions, *, t_min=0.0, t_max=np.inf, axis=None):
    """All watertight hits of rays on a triangle soup, sorted by (ray, t).

    Parameters
    ----------
    triangles : (T, 3, 3) float
    origins, directions : (n, 3) or (3,) float
        As for :func:`trace_rays`.
    t_min, t_max : float or (n,) float
    axis : (3,) float, optional
        Beam axis for culling (see :func:`~xray_viz.tracing.candidates.candidate_pairs`).

    Returns
    -------
    ray, tri : (k,) int
    t : (k,) float
    bary : (k, 3) float
    entering : (k,) bool

    Raises
    ------
    SceneError
        Malformed triangles, rays, ranges or axis (see :func:`trace_rays`).
    """
    tri = np.asarray(triangles)
    if tri.dtype.kind not in "iuf" or tri.size % 9 or (tri.ndim == 3 and tri.shape[1:] != (3, 3)):
        raise SceneError(f"triangles must be a (T, 3, 3) array of numbers, got shape "
                         f"{tri.shape} dtype {tri.dtype}")
    triangles = tri.astype(np.float64, copy=False).reshape(-1, 3, 3)
    if not np.all(np.isfinite(triangles)):
        raise SceneError("triangles must be finite")
    origins, directions = _check_rays(origins, directions)
    n = len(directions)
    t_min = _broadcast_range(t_min, n, "t_min")
    t_max = _broadcast_range(t_max, n, "t_max")
    axis = _check_axis(axis)
    out = {k: [] for k in ("ray", "tri", "t", "bary", "entering")}
    for ray, tri in candidate_pairs(triangles, origins, directions, t_min, t_max, axis=axis):
        v = triangles[tri]
        hit, t, bary, entering = watertight_intersect(
            origins[ray], directions[ray], v[:, 0], v[:, 1], v[:, 2],
            t_min=t_min[ray], t_max=t_max[ray])
        for key, val in (("ray", ray), ("tri", tri), ("t", t), ("bary", bary),
                         ("entering", entering)):
            out[key].append(val[hit])
    if not out["ray"]:
        return (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)),
                np.zeros(0, bool))
    ray, tri, t, bary, entering = (np.concatenate(out[k]) for k in
                                   ("ray", "tri", "t", "bary", "entering"))
    order = np.lexsort((t, ray))
    return ray[order], tri[order], t[order], bary[order], entering[order]


def trace_rays(scene, origins, directions, *, t_min=0.0, t_max=np.inf, axis=None) -> Hits:
    """Trace any set of rays through a scene's bodies and return every hit.

    A public adapter (``xray_viz.trace_rays(scene, ...)`` in the README): a scene gives its
    bodies; the tracer itself reads only the bodies' triangles.

    Parameters
    ----------
    scene : Scene or Bodies
        The bodies to trace (a scene's source and detector are not used).
    origins : (n, 3) or (3,) float
        Ray origins (mm), finite.
    directions : (n, 3) or (3,) float
        Ray directions, finite and non-zero (any length; ``t`` is in units of the direction's
        length, which must be between about 1e-154 and 1e154 so that its square is a float64).
        A single ray's origin or direction, shape (3,) or (1, 3), is shared by all the other's
        rows (one source, many directions; or parallel rays); otherwise both have n rows.
    t_min, t_max : float or (n,) float, optional
        Only hits with ``t_min <= t <= t_max`` are reported (not NaN; ``t_max`` may be inf).
    axis : (3,) float, optional
        Beam axis, a hint for culling.

    Returns
    -------
    Hits
        Flat arrays sorted by (ray, t).

    Raises
    ------
    SceneError
        Arrays of the wrong shape or type (strings, bools, complex), non-finite origins or
        directions, zero directions, or origins and directions with different numbers of rows.

    Examples
    --------
    >>> import numpy as np, xray_viz
    >>> scene = xray_viz.load_scene("sphere")
    >>> hits = xray_viz.trace_rays(scene, [0, 0, 1000], [[0, 0, -1]])
    >>> hits.entering.tolist(), np.round(hits.t, 1).tolist()
    ([True, False], [960.0, 1040.0])
    """
    origins, directions = _check_rays(origins, directions)
    ray, tri, t, bary, entering = trace_triangles(
        scene.triangles, origins, directions, t_min=t_min, t_max=t_max, axis=axis)
    body = scene.triangle_body[tri]
    local = tri - scene.triangle_offset[body]
    point = origins[ray] + t[:, None] * directions[ray]
    return Hits(ray=ray, t=t, point=point, triangle=local, body=body, barycentric=bary,
                entering=entering)


def inside_counts(triangles, points, *, direction=PROBE) -> np.ndarray:
    """Winding number of a closed mesh around points: exits minus entries along a probe ray.

    1 for a point inside an outward-oriented closed mesh, 0 outside.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    dirs = np.broadcast_to(direction, points.shape)
    ray, _, _, _, entering = trace_triangles(triangles, points, dirs, t_min=0.0)
    return np.bincount(ray, weights=np.where(entering, -1, 1), minlength=len(points)).astype(int)
