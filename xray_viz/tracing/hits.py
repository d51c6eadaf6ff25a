"""All hits of a set of rays: flat arrays sorted by (ray, t), trimesh style."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from xray_viz.tracing.candidates import candidate_pairs
from xray_viz.tracing.intersect import watertight_intersect

__all__ = ["Hits", "trace_triangles", "trace_rays"]


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


def _broadcast_range(value, n):
    return np.broadcast_to(np.asarray(value, dtype=np.float64), (n,))


def trace_triangles(triangles, origins, directions, *, t_min=0.0, t_max=np.inf, axis=None):
    """All watertight hits of rays on a triangle soup, sorted by (ray, t).

    Parameters
    ----------
    triangles : (T, 3, 3) float
    origins, directions : (n, 3) float
    t_min, t_max : float or (n,) float
    axis : (3,) float, optional
        Beam axis for culling (see :func:`~xray_viz.tracing.candidates.candidate_pairs`).

    Returns
    -------
    ray, tri : (k,) int
    t : (k,) float
    bary : (k, 3) float
    entering : (k,) bool
    """
    triangles = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    n = len(directions)
    origins = np.broadcast_to(origins, (n, 3))
    t_min = _broadcast_range(t_min, n)
    t_max = _broadcast_range(t_max, n)
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

    Parameters
    ----------
    scene : Scene
        The bodies to trace (source and detector are not used).
    origins : (n, 3) or (3,) float
        Ray origins.
    directions : (n, 3) float
        Ray directions (any length; ``t`` is in units of the direction's length).
    t_min, t_max : float or (n,) float, optional
        Only hits with ``t_min <= t <= t_max`` are reported.
    axis : (3,) float, optional
        Beam axis, a hint for culling.

    Returns
    -------
    Hits
        Flat arrays sorted by (ray, t).

    Examples
    --------
    >>> import numpy as np, xray_viz
    >>> scene = xray_viz.load_scene("sphere")
    >>> hits = xray_viz.trace_rays(scene, [0, 0, 1000], [[0, 0, -1]])
    >>> hits.entering.tolist(), np.round(hits.t, 1).tolist()
    ([True, False], [960.0, 1040.0])
    """
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    origins = np.broadcast_to(np.asarray(origins, dtype=np.float64).reshape(-1, 3),
                              directions.shape)
    ray, tri, t, bary, entering = trace_triangles(
        scene.triangles, origins, directions, t_min=t_min, t_max=t_max, axis=axis)
    body = scene.triangle_body[tri]
    local = tri - scene.triangle_offset[body]
    point = origins[ray] + t[:, None] * directions[ray]
    return Hits(ray=ray, t=t, point=point, triangle=local, body=body, barycentric=bary,
                entering=entering)
