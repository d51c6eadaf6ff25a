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

__all__ = ["path_lengths", "body_precedence", "rank_by_nesting", "remember_precedence", "check_source_outside",
           "inside_counts", "mesh_bounds", "beam_planes", "boxes_outside_beam"]

#: A fixed, irrational-looking direction for inside/outside tests (no axis, no diagonal).
PROBE = np.array([0.5377, 0.3141, 0.7826]) / np.linalg.norm([0.5377, 0.3141, 0.7826])


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


def inside_counts(triangles, points, *, direction=PROBE) -> np.ndarray:
    """Winding number of a closed mesh around points: exits minus entries along a probe ray.

    1 for a point inside an outward-oriented closed mesh, 0 outside.
    """
    from xray_viz.tracing.hits import trace_triangles

    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    dirs = np.broadcast_to(direction, points.shape)
    ray, _, _, _, entering = trace_triangles(triangles, points, dirs, t_min=0.0)
    return np.bincount(ray, weights=np.where(entering, -1, 1), minlength=len(points)).astype(int)


def body_precedence(scene) -> np.ndarray:
    """Rank the bodies: a body wholly inside another wins there; otherwise list order.

    Body ``a`` is *inside* body ``b`` when its surface does not cross ``b``'s (no triangle of
    one meets a triangle of the other: :func:`xray_viz.meshes.repair.surfaces_cross`) and a
    point of each of its pieces lies inside ``b``: exact, not a vote of sampled vertices, so a
    body 99 % inside another is not nested (it only overlaps it). The rank is list order
    moved as little as needed so that every body ranks above each body containing it (a
    topological order of "is inside" with the earliest-listed body placed first): nested
    bodies, innermost wins (marrow in bone in soft tissue); partly overlapping bodies, the
    later-listed wins.

    Returns
    -------
    (n_bodies,) int
        A permutation of ``range(n_bodies)``; higher wins.

    Examples
    --------
    >>> import trimesh, xray_viz
    >>> from xray_viz.scene import Body, Detector, Scene, Source
    >>> big = trimesh.creation.box(extents=[40, 40, 40])
    >>> small = trimesh.creation.box(extents=[10, 10, 10])
    >>> scene = Scene(source=Source(position=[0, 0, 1000]), detector=Detector(center=[0, 0, -500]),
    ...               bodies=(Body(name="small", mesh=small, mu=1.0),
    ...                       Body(name="big", mesh=big, mu=0.2)))
    >>> body_precedence(scene).tolist()          # small is inside big: it wins, though first
    [1, 0]
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
    from xray_viz.meshes.repair import containers

    return rank_by_nesting(containers([b.mesh for b in bodies]))


def rank_by_nesting(containers) -> np.ndarray:
    """Precedence from nesting: list order, moved as little as needed so that each body ranks
    above every body containing it.

    Parameters
    ----------
    containers : list of list of int
        ``containers[a]``: the bodies that body ``a`` lies wholly inside.

    Returns
    -------
    (n,) int
        A permutation of ``range(n)``; higher wins.

    Examples
    --------
    >>> rank_by_nesting([[], [0], []]).tolist()       # 1 inside 0; 2 overlaps, listed last
    [0, 1, 2]
    >>> rank_by_nesting([[1], [], []]).tolist()       # 0 inside 1: 0 wins over 1
    [1, 0, 2]
    """
    import heapq

    n = len(containers)
    # Kahn's algorithm, lowest rank first; among the bodies free to place, the earliest listed
    waiting = [len(c) for c in containers]
    inner = [[] for _ in range(n)]
    for a, cs in enumerate(containers):
        for b in cs:
            inner[b].append(a)
    free = [a for a in range(n) if waiting[a] == 0]
    heapq.heapify(free)
    rank = np.empty(n, int)
    k = 0
    while free:
        b = heapq.heappop(free)
        rank[b] = k
        k += 1
        for a in inner[b]:
            waiting[a] -= 1
            if waiting[a] == 0:
                heapq.heappush(free, a)
    if k < n:                                 # mutual containment: identical bodies
        rest = [a for a in range(n) if waiting[a] > 0]
        rank[rest] = k + np.arange(len(rest))
    return rank


def mesh_bounds(mesh) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounding box ``(lo, hi)`` of a mesh's vertices, cached per mesh data.

    The cache is keyed by the mesh object and its data hash (trimesh keeps the hash until the
    vertices or faces change), so a changed mesh is measured again; a new :class:`Scene` made
    with ``replace`` (the viewer moving the source) costs a dictionary look-up, not a pass over
    the vertices.
    """
    try:
        key = (id(mesh), hash(mesh))
    except TypeError:
        key = None
    if key is not None:
        hit = _BOUNDS.get(key)
        if hit is not None:
            _BOUNDS.move_to_end(key)
            return hit
    lo, hi = _measure(mesh)
    for a in (lo, hi):
        a.setflags(write=False)
    if key is not None:
        _BOUNDS[key] = (lo, hi)
        while len(_BOUNDS) > 256:
            _BOUNDS.popitem(last=False)
    return lo, hi


_BOUNDS: "OrderedDict[tuple, tuple]" = OrderedDict()


def _measure(mesh):
    v = np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3)
    if len(v):
        return v.min(axis=0), v.max(axis=0)
    return np.full(3, np.inf), np.full(3, -np.inf)


def beam_planes(r0, forward, eu, ev, FL, half_u, half_v, perspective) -> np.ndarray:
    """Planes bounding the beam: every ray point ``x`` has ``n . (x - r0) <= c`` for each row
    ``(nx, ny, nz, c)`` of the result.

    Rows 0-3 are the side planes (through the source for a point source: the pyramid from the
    source through the detector rectangle of half-widths ``half_u``, ``half_v`` mm along ``eu``
    and ``ev``; the slab box of a parallel beam), row 4 the source plane (nothing behind it),
    row 5 the detector plane (rays end there, ``FL`` from the source).
    """
    f = np.asarray(forward, np.float64)
    eu = np.asarray(eu, np.float64)
    ev = np.asarray(ev, np.float64)
    rows = []
    for e, h in ((eu, half_u), (ev, half_v)):
        for s in (1.0, -1.0):
            if perspective:
                rows.append(np.append(s * FL * e - h * f, 0.0))   # |a| FL <= h w
            else:
                rows.append(np.append(s * e, h))                  # |a| <= h
    rows.append(np.append(-f, 0.0))
    rows.append(np.append(f, FL))
    return np.ascontiguousarray(rows, dtype=np.float64)


def beam_half_widths(detector) -> tuple[float, float]:
    """Half-widths (mm) of a detector's ray grid, any supersampling included, plus one pixel:
    a margin far above rounding and fixed-point snapping, so culling by them is conservative."""
    (w, h), (pu, pv) = detector.shape, detector.pitch
    return (w / 2 + 1) * pu, (h / 2 + 1) * pv


def boxes_outside_beam(lo, hi, r0, planes) -> np.ndarray:
    """(n,) bool: which boxes ``[lo[k], hi[k]]`` lie wholly outside one of the beam's
    ``planes`` (see :func:`beam_planes`), so that no ray of the beam meets what is inside them.

    Exact up to a relative margin of 1e-12 kept on the safe (not outside) side.
    """
    lo = np.asarray(lo, np.float64).reshape(-1, 3)
    hi = np.asarray(hi, np.float64).reshape(-1, 3)
    n, c = planes[:, :3], planes[:, 3]
    mid, half = (lo + hi) / 2 - r0, (hi - lo) / 2
    nearest = mid @ n.T - half @ np.abs(n).T            # min of n . (x - r0) over each box
    scale = (np.abs(mid) + half) @ np.abs(n).T + np.abs(c)
    return np.any(nearest - c > 1e-12 * scale, axis=1)


def check_source_outside(scene) -> None:
    """Refuse a scene whose rays would start inside a body.

    A parallel beam's rays start on the source plane (through the source, across the beam);
    a body crossing that plane is refused only where the crossing can lie within the beam
    (the rectangle of the rays' starting points, widened by a pixel). Bounding boxes are
    cached per mesh (:func:`mesh_bounds`), so this costs no pass over the vertices for a
    body wholly in front of the source plane or, for a point source, not around the source.

    Raises
    ------
    SceneError
        If the point source is inside a body, or a parallel beam's source plane cuts a body
        across the beam.
    """
    from xray_viz.geometry import detector_axes

    r0 = scene.source.position
    where = f"{scene.path}: " if scene.path else ""
    if not scene.bodies:
        return
    parallel = scene.source.kind == "parallel"
    boxes = [mesh_bounds(body.mesh) for body in scene.bodies]
    if parallel:
        forward, eu, ev = detector_axes(r0, scene.detector.center, scene.detector.up)
        hu, hv = beam_half_widths(scene.detector)
        slab = beam_planes(r0, forward, eu, ev, 0.0, hu, hv, False)[:4]
        aside = boxes_outside_beam([b[0] for b in boxes], [b[1] for b in boxes], r0, slab)
    for k, body in enumerate(scene.bodies):
        lo, hi = boxes[k]
        if parallel:
            mid, half = (lo + hi) / 2 - r0, (hi - lo) / 2
            centre, reach = float(mid @ forward), float(half @ np.abs(forward))
            if aside[k] or not centre - reach < 0 < centre + reach:
                continue
            v = body.vertices
            depth = (v - r0) @ forward
            if not depth.min() < 0 < depth.max():
                continue
            if _crosses_within(body, v - r0, depth, eu, ev, hu, hv) or \
                    _winding(v[body.faces], r0) > 0:
                raise SceneError(
                    f"{where}body {body.name!r} crosses the plane of the parallel-beam source "
                    f"(through {r0.tolist()}, across the beam): move the source back")
            continue
        if np.any(r0 < lo) or np.any(r0 > hi):
            continue
        if _winding(body.vertices[body.faces], r0) > 0:
            raise SceneError(
                f"{where}the source {r0.tolist()} is inside body {body.name!r}: move the "
                "source outside every body")


def _winding(tris, point) -> int:
    return max(inside_counts(tris, point, direction=d)[0]
               for d in (PROBE, np.array([-0.6, 0.48, -0.64])))


def _crosses_within(body, rel, depth, eu, ev, hu, hv) -> bool:
    """Does a face of the body meeting the source plane reach into the beam's rectangle?"""
    f = body.faces
    d = depth[f]
    meet = (d.min(axis=1) <= 0) & (d.max(axis=1) >= 0)
    if not meet.any():
        return False
    tri = rel[f[meet]]
    a, b = tri @ eu, tri @ ev
    return bool(np.any((a.min(axis=1) <= hu) & (a.max(axis=1) >= -hu)
                       & (b.min(axis=1) <= hv) & (b.max(axis=1) >= -hv)))
