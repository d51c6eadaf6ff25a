"""From hits to path lengths: which material each stretch of each ray crosses.

For each ray the hits are swept in order of ``t``; after each hit we know which bodies the ray is
inside (entries minus exits of that body > 0). The material of a stretch of ray is the body with
the highest *precedence* among those it is inside:

* **nested bodies: innermost wins** - a body inside another replaces the outer material there
  (marrow inside bone inside soft tissue);
* **partial overlaps: the later-listed body wins** in the overlap.

The *effective path length* ``L[ray, body]`` is the length of ray (in mm) whose material is that
body; the line integral of Beer-Lambert's law is then ``sum_b mu_b * L[:, b]`` (Eq. in
:mod:`xray_viz.physics`). Rays end at the detector (``t_max``): a body reaching past the detector
is counted up to it.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from xray_viz.errors import SceneError

__all__ = ["path_lengths", "body_precedence", "remember_precedence", "check_source_outside",
           "inside_counts"]

#: A fixed, irrational-looking direction for inside/outside tests (no axis, no diagonal).
_PROBE = np.array([0.5377, 0.3141, 0.7826]) / np.linalg.norm([0.5377, 0.3141, 0.7826])


def path_lengths(ray, t, body, entering, *, n_rays, n_bodies, precedence, t_max):
    """Effective path length of every ray through every body's material.

    Parameters
    ----------
    ray, t, body, entering : (k,) arrays
        Hits sorted by (ray, t), as in :class:`~xray_viz.tracing.Hits`.
    n_rays, n_bodies : int
    precedence : (n_bodies,) int
        Rank of each body; the highest rank among the bodies containing a point gives its material.
    t_max : (n_rays,) float
        Where each ray ends (the detector).

    Returns
    -------
    (n_rays, n_bodies) float
        Millimetres of each ray inside each body's material. A row sums to the length of ray
        that is inside any body.

    Examples
    --------
    A ray entering body 0 at t=1, body 1 (nested, higher rank) at t=2, leaving 1 at t=3 and
    0 at t=5:

    >>> import numpy as np
    >>> L = path_lengths(np.zeros(4, int), np.array([1., 2, 3, 5]), np.array([0, 1, 1, 0]),
    ...                  np.array([True, True, False, False]), n_rays=1, n_bodies=2,
    ...                  precedence=np.array([0, 1]), t_max=np.array([10.0]))
    >>> L.tolist()
    [[3.0, 1.0]]
    """
    out = np.zeros((n_rays, n_bodies))
    k = len(ray)
    if k == 0 or n_bodies == 0:
        return out
    ray = np.asarray(ray)
    t = np.asarray(t, dtype=np.float64)
    body = np.asarray(body)
    delta = np.where(entering, 1, -1).astype(np.int32)
    first = np.ones(k, bool)
    first[1:] = ray[1:] != ray[:-1]
    start_of = np.maximum.accumulate(np.where(first, np.arange(k), 0))
    winner = np.full(k, -1, np.int64)
    for b in np.argsort(precedence, kind="stable"):
        cs = np.cumsum(np.where(body == b, delta, 0))
        before = np.concatenate([[0], cs])[start_of]
        winner = np.where(cs - before > 0, b, winner)
    t_end = np.asarray(t_max, dtype=np.float64)[ray]
    nxt = np.empty(k)
    nxt[:-1] = np.where(ray[1:] == ray[:-1], t[1:], t_end[:-1])
    nxt[-1] = t_end[-1]
    seg = np.maximum(nxt - t, 0.0)
    sel = winner >= 0
    flat = np.bincount(ray[sel] * n_bodies + winner[sel], weights=seg[sel],
                       minlength=n_rays * n_bodies)
    return flat.reshape(n_rays, n_bodies)


def inside_counts(triangles, points, *, direction=_PROBE) -> np.ndarray:
    """Winding number of a closed mesh around points: exits minus entries along a probe ray.

    1 for a point inside an outward-oriented closed mesh, 0 outside.
    """
    from xray_viz.tracing.hits import trace_triangles

    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    dirs = np.broadcast_to(direction, points.shape)
    ray, _, _, _, entering = trace_triangles(triangles, points, dirs, t_min=0.0)
    return np.bincount(ray, weights=np.where(entering, -1, 1), minlength=len(points)).astype(int)


def _sample_vertices(vertices, n=24):
    idx = np.linspace(0, len(vertices) - 1, min(n, len(vertices))).astype(int)
    return vertices[idx]


def body_precedence(scene) -> np.ndarray:
    """Rank the bodies: containment depth first (innermost wins), then list order.

    A body counts as inside another when most of a sample of its vertices are inside it.

    Returns
    -------
    (n_bodies,) int
        A permutation of ``range(n_bodies)``; higher wins.
    """
    bodies = scene.bodies
    key = _bodies_key(bodies)
    if key is not None and key in _PRECEDENCE:
        _PRECEDENCE.move_to_end(key)
        return _PRECEDENCE[key].copy()
    rank = _body_precedence(bodies)
    remember_precedence(bodies, rank)
    return rank


def remember_precedence(bodies, rank) -> None:
    """Record ``rank`` as :func:`body_precedence` of these bodies, as their meshes are now.

    For bodies derived from ranked ones by a map that keeps nesting and overlaps (an
    orientation-preserving affine transform of all of them: see
    :meth:`xray_viz.scene.Scene.transform_bodies`).
    """
    key = _bodies_key(bodies)
    if key is None:
        return
    _PRECEDENCE[key] = np.array(rank, dtype=int)
    while len(_PRECEDENCE) > 16:
        _PRECEDENCE.popitem(last=False)


def _bodies_key(bodies):
    try:                       # trimesh's hash follows the vertex and face data
        return tuple((id(b.mesh), hash(b.mesh)) for b in bodies)
    except TypeError:
        return None


#: Precedence of recently seen sets of bodies: a new Scene with the same meshes (the source
#: moved, the energy changed) reuses it instead of testing containment again.
_PRECEDENCE: "OrderedDict[tuple, np.ndarray]" = OrderedDict()


def _body_precedence(bodies) -> np.ndarray:
    n = len(bodies)
    depth = np.zeros(n, int)
    boxes = [(b.vertices.min(0), b.vertices.max(0)) for b in bodies]
    for a in range(n):
        samples = _sample_vertices(bodies[a].vertices)
        for b in range(n):
            if a == b:
                continue
            (alo, ahi), (blo, bhi) = boxes[a], boxes[b]
            if np.any(alo < blo) or np.any(ahi > bhi):
                continue
            tris = bodies[b].vertices[bodies[b].faces]
            inside = inside_counts(tris, samples) > 0
            if inside.mean() > 0.5:
                depth[a] += 1
    order = np.lexsort((np.arange(n), depth))
    rank = np.empty(n, int)
    rank[order] = np.arange(n)
    return rank


def check_source_outside(scene) -> None:
    """Refuse a scene whose rays would start inside a body.

    Raises
    ------
    SceneError
        If the point source is inside a body, or a parallel beam's source plane cuts a body.
    """
    from xray_viz.geometry import beam_direction

    r0 = scene.source.position
    forward = beam_direction(r0, scene.detector.center)
    where = f"{scene.path}: " if scene.path else ""
    for body in scene.bodies:
        v = body.vertices
        if scene.source.kind == "parallel":
            depth = (v - r0) @ forward
            if depth.min() < 0 < depth.max():
                raise SceneError(
                    f"{where}body {body.name!r} crosses the plane of the parallel-beam source "
                    f"(through {r0.tolist()}, across the beam): move the source back")
            continue
        lo, hi = v.min(0), v.max(0)
        if np.any(r0 < lo) or np.any(r0 > hi):
            continue
        tris = v[body.faces]
        wind = [inside_counts(tris, r0, direction=d)[0]
                for d in (_PROBE, np.array([-0.6, 0.48, -0.64]))]
        if max(wind) > 0:
            raise SceneError(
                f"{where}the source {r0.tolist()} is inside body {body.name!r}: move the "
                "source outside every body")
