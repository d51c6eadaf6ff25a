"""From hits to path lengths: which material each stretch of each ray crosses.

For each ray the hits are swept in order of ``t``; after each hit we know which bodies the ray is
inside (entries minus exits of that body > 0). The material of a stretch of ray is the body with
the highest *precedence* among those it is inside:

* **nested bodies: innermost wins** - a body inside another replaces the outer material there
  (marrow inside bone inside soft tissue);
* **partial overlaps: the later-listed body wins** in the overlap;
* **a volume's bodies (a meshed ``[[ct]]`` or ``[[labels]]``) rank below the scene's own
  meshes** that they do not lie inside (:func:`below_meshes`): an implant in a CT replaces the
  tissue *and the bone* it displaces, whatever it touches, as in a voxel trace.

The *effective path length* ``L[ray, body]`` is the length of ray (in mm) whose material is that
body; the line integral of Beer-Lambert's law is then ``sum_b mu_b * L[:, b]`` (Eq. in
:mod:`xray_viz.physics`). Rays end at the detector (``t_max``): a body reaching past the detector
is counted up to it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["path_lengths", "stretch_materials", "body_precedence", "rank_by_nesting",
           "below_meshes"]


def stretch_materials(ray, body, entering, *, precedence) -> np.ndarray:
    """Which body's material fills the stretch of ray after each hit: the sweep.

    The hits of each ray are swept in order of ``t``, counting entries minus exits per body
    (its winding number: the nonzero rule); after each hit the material is that of the body
    of highest ``precedence`` among those with a positive count. This is the one sweep of
    xray_viz: the path lengths of the reference engine, the viewer's inside segments and its
    mu(t) profile all come from it (the fast engine's numba kernel implements the same rule
    and is tested against it).

    Parameters
    ----------
    ray, body, entering : (k,) arrays
        Hits sorted by (ray, t), as in :class:`~xray_viz.tracing.Hits`.
    precedence : (n_bodies,) int
        Rank of each body; higher wins.

    Returns
    -------
    (k,) int
        The body filling the stretch from hit ``i`` to the next hit of the same ray (or to
        the ray's end), -1 where the ray is inside no body.

    Examples
    --------
    >>> import numpy as np
    >>> stretch_materials(np.zeros(4, int), np.array([0, 1, 1, 0]),
    ...                   np.array([True, True, False, False]), precedence=np.array([0, 1])
    ...                   ).tolist()
    [0, 1, 0, -1]
    """
    ray = np.asarray(ray)
    body = np.asarray(body)
    k = len(ray)
    winner = np.full(k, -1, np.int64)
    if k == 0:
        return winner
    delta = np.where(entering, 1, -1).astype(np.int32)
    first = np.ones(k, bool)
    first[1:] = ray[1:] != ray[:-1]
    start_of = np.maximum.accumulate(np.where(first, np.arange(k), 0))
    for b in np.argsort(precedence, kind="stable"):
        cs = np.cumsum(np.where(body == b, delta, 0))
        before = np.concatenate([[0], cs])[start_of]
        winner = np.where(cs - before > 0, b, winner)
    return winner


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
    winner = stretch_materials(ray, body, entering, precedence=precedence)
    t_end = np.asarray(t_max, dtype=np.float64)[ray]
    nxt = np.empty(k)
    nxt[:-1] = np.where(ray[1:] == ray[:-1], t[1:], t_end[:-1])
    nxt[-1] = t_end[-1]
    seg = np.maximum(nxt - t, 0.0)
    sel = winner >= 0
    flat = np.bincount(ray[sel] * n_bodies + winner[sel], weights=seg[sel],
                       minlength=n_rays * n_bodies)
    return flat.reshape(n_rays, n_bodies)


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

    Computed once per set of meshes and kept by the scene's
    :class:`~xray_viz.bodies.Bodies` (:attr:`~xray_viz.bodies.Bodies.precedence`); this
    returns a copy.

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
    kept = getattr(scene.bodies, "precedence", None)      # a Bodies keeps it
    return np.array(kept) if kept is not None else _body_precedence(scene.bodies)


def _body_precedence(bodies) -> np.ndarray:
    """:func:`body_precedence` computed afresh for a sequence of bodies (nothing kept)."""
    from xray_viz.meshes._volume_files import is_volume_path
    from xray_viz.meshes.repair import containers

    inside = containers([b.mesh for b in bodies])
    meshed = [getattr(b, "source_file", None) is not None and is_volume_path(b.source_file)
              for b in bodies]
    return rank_by_nesting(below_meshes(inside, meshed))


def below_meshes(containers, from_volume):
    """Nesting with a volume's bodies placed under the scene's own meshes.

    A body meshed from a volume (a CT's tissue classes, a label map's labels) is a piece of
    one material field: a ``[[body]]`` mesh in it displaces that field wherever it is, as it
    would in the voxels. So each ``[[body]]`` mesh ranks above every volume body, unless that
    volume body lies wholly inside it (a CT inside a water tank: the CT wins there, innermost
    wins). Without this rule an implant touching the CT's bone only *overlaps* the bone, and
    the bone, listed after the ``[[body]]`` tables, would erase it there.

    Parameters
    ----------
    containers : list of list of int
        ``containers[a]``: the bodies that body ``a`` lies wholly inside.
    from_volume : sequence of bool
        Which bodies were meshed from a volume.

    Returns
    -------
    list of list of int
        ``containers`` with, for each mesh ``a`` and volume body ``v`` not inside ``a``,
        ``v`` added to ``containers[a]`` (so that :func:`rank_by_nesting` ranks ``a`` above).

    Examples
    --------
    >>> below_meshes([[1], [], []], [False, True, True])   # 0 is in 1; 2 overlaps 0
    [[1, 2], [], []]
    >>> rank_by_nesting(below_meshes([[1], [], []], [False, True, True])).tolist()
    [2, 0, 1]
    """
    out = [list(c) for c in containers]
    volume = [k for k, v in enumerate(from_volume) if v]
    for a, v_a in enumerate(from_volume):
        if v_a:
            continue
        for v in volume:
            if a not in containers[v] and v not in out[a]:
                out[a].append(v)
    return out


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
