"""Numerical stability stress suite: zero miscounted rays on adversarial configurations.

Every case checks exact path lengths, for BOTH engines (``fast`` and ``numpy``), against a
reference computed in exact integer arithmetic:

* the 12-triangle cube [-20, 20]^3 seen by a point source and by a parallel beam whose rays run
  along edges, face diagonals, through vertices and inside the side-face planes;
* convex polyhedra with every vertex on an integer lattice, turned by random *rational* rotations
  (Pythagorean quaternions, so the rotated vertices stay on the lattice) and translated by
  random integers, seen through a detector placed so that its rays pass exactly through chosen
  vertices and edge points: parallel beam, rays on the lattice through a chosen vertex; point
  source, a chosen vertex on the central ray and the detector twice as far, so that the rays
  cross the vertex's plane on the lattice and pass through interior points of its edges. For
  both beams the rays through vertices and through edge points are counted exactly (all
  vertices, all edges) and must be > 0. The chord of a ray through a convex polyhedron is the
  intersection of half-spaces, computed exactly with Python integers;
* arbitrary rays (any direction, not a detector grid) aimed exactly at every vertex and edge
  midpoint of such a polyhedron: the NumPy engine's ``trace_rays`` finds exactly one entry (at
  the aimed point) and one exit, and the exact chord;
* far sources (1e5 mm), tiny bodies (1e-3 mm, scaled by a power of two so that scaling is exact),
  large coordinate offsets (1e6 mm), slivers (aspect ratio ~1000) and zero-area triangles
  (a T-junction closed by a degenerate triangle), many nested shells.

Rays lying exactly in a face plane cross a set of measure zero: the result must be one of the two
one-sided limits (0 or the closed chord). ``-m slow`` runs many more random cases.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz.geometry import detector_rays
from helpers import box_chord, make_scene

pytestmark = pytest.mark.stress
ENGINES = ("fast", "numpy")


# --------------------------------------------------------------------------------------------
# Exact references


def rational_rotation(rng):
    """An integer matrix ``s * R`` with R a rotation and ``s = a^2 + b^2 + c^2 + d^2``."""
    while True:
        a, b, c, d = (int(x) for x in rng.integers(-2, 3, size=4))
        s = a * a + b * b + c * c + d * d
        if s > 1:
            break
    m = np.array([
        [a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c)],
        [2 * (b * c + a * d), a * a - b * b + c * c - d * d, 2 * (c * d - a * b)],
        [2 * (b * d - a * c), 2 * (c * d + a * b), a * a - b * b - c * c + d * d]], np.int64)
    return m, s


def lattice_hull(rng, *, n_points=14, half=6):
    """A convex polyhedron with integer vertices containing the origin strictly inside."""
    while True:
        pts = rng.integers(-half, half + 1, size=(n_points, 3))
        pts = np.vstack([pts, [[half, 0, 0], [-half, 0, 0], [0, half, 0], [0, -half, 0],
                               [0, 0, half], [0, 0, -half]]])
        hull = trimesh.convex.convex_hull(pts)
        rot, _ = rational_rotation(rng)
        v = np.rint(hull.vertices).astype(np.int64) @ rot.T
        mesh = trimesh.Trimesh(v.astype(float), hull.faces.copy(), process=False)
        if mesh.volume < 0:
            mesh.invert()
        planes = face_planes(np.rint(mesh.vertices).astype(np.int64), mesh.faces)
        if np.all(np.array([c for _, c in planes], dtype=object) > 0):
            return np.rint(mesh.vertices).astype(np.int64), np.asarray(mesh.faces)


def face_planes(v, faces):
    """Outward planes ``n . x <= c`` of a convex mesh, as Python integers."""
    out = []
    for f in faces:
        a, b, c = (v[k].tolist() for k in f)
        e1 = [b[i] - a[i] for i in range(3)]
        e2 = [c[i] - a[i] for i in range(3)]
        n = [e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
             e1[0] * e2[1] - e1[1] * e2[0]]
        if n != [0, 0, 0]:
            out.append((n, sum(n[i] * a[i] for i in range(3))))
    return out


def _may_meet(box, o, d, tm):
    lo, hi = box
    t0, t1 = 0.0, float(tm)
    for i in range(3):
        if d[i] == 0:
            if not lo[i] <= o[i] <= hi[i]:
                return False
            continue
        a, b = (lo[i] - o[i]) / d[i], (hi[i] - o[i]) / d[i]
        t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
    return t0 <= t1 + 1e-9 * (1 + abs(t1))


def exact_chords(planes, origins, directions, t_max, *, box=None):
    """Closed chord (in units of t) of integer rays through a convex polyhedron, exactly.

    Returns
    -------
    length : (n,) float
        ``t_exit - t_enter`` of the closed polyhedron, clipped to ``[0, t_max]``.
    in_plane : (n,) bool
        The ray lies in a face plane and meets the polyhedron: its length is ambiguous.
    """
    from fractions import Fraction

    lengths, ambiguous = [], []
    # Rays that miss the (inflated) bounding box of the planes' vertices cannot meet the body:
    # a conservative float prefilter, the exact test decides the rest.
    for o, d, tm in zip(origins.tolist(), directions.tolist(), t_max):
        if box is not None and not _may_meet(box, o, d, tm):
            lengths.append(0.0)
            ambiguous.append(False)
            continue
        lo, hi = Fraction(0), Fraction(tm)
        empty = in_plane = False
        for n, c in planes:
            den = n[0] * d[0] + n[1] * d[1] + n[2] * d[2]
            num = c - (n[0] * o[0] + n[1] * o[1] + n[2] * o[2])
            if den == 0:
                if num < 0:
                    empty = True
                    break
                in_plane |= num == 0
            elif den > 0:
                hi = min(hi, Fraction(num, den))
            else:
                lo = max(lo, Fraction(num, den))
        ok = not empty and hi > lo
        lengths.append(float(hi - lo) if ok else 0.0)
        ambiguous.append(ok and in_plane)
    return np.array(lengths), np.array(ambiguous)


def integer_rays(source, center, shape, pitch, kind):
    """The detector rays of an axis-aligned (beam along -z) integer scene, exactly.

    Returns integer origins, integer directions and t_max (in units of the direction).
    """
    w, h = shape
    i = np.arange(w) - (w - 1) // 2
    j = np.arange(h)[::-1] - (h - 1) // 2
    gx, gy = np.meshgrid(i * pitch, j * pitch)
    n = gx.size
    if kind == "parallel":
        origins = np.column_stack([gx.ravel() + source[0], gy.ravel() + source[1],
                                   np.full(n, source[2])])
        directions = np.tile([0, 0, -1], (n, 1))
        t_max = [source[2] - center[2]] * n
    else:
        targets = np.column_stack([gx.ravel() + center[0], gy.ravel() + center[1],
                                   np.full(n, center[2])])
        origins = np.tile(source, (n, 1))
        directions = targets - origins
        t_max = [1] * n
    return origins.astype(np.int64), directions.astype(np.int64), t_max


def check_lengths(L, ref, ambiguous, *, atol):
    """Count miscounted rays: away from ``ref`` (or from both limits where ambiguous)."""
    ok = np.abs(L - ref) <= atol
    ok |= ambiguous & ((np.abs(L) <= atol) | (np.abs(L - ref) <= atol))
    return np.count_nonzero(~ok)


# --------------------------------------------------------------------------------------------
# The cube suite


def cube_scene(kind, shape=(255, 255)):
    cube = trimesh.creation.box(extents=(40.0, 40.0, 40.0))
    return make_scene(cube, source=(0.0, 0.0, -1000.0), center=(0.0, 0.0, 249.5),
                      up=(0.0, 1.0, 0.0), shape=shape, pitch=0.5, kind=kind)


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_cube_suite_zero_miscounted_rays(engine, kind):
    scene = cube_scene(kind)
    rays = detector_rays(scene)
    L = xray_viz.render(scene, engine=engine).total_path_length.ravel()
    ref, _, _ = box_chord(rays.origins, rays.directions, [-20] * 3, [20] * 3, rays.t_max)
    # Ideal grid positions (mm) of the rays: (col - 127) / 2, (127 - row) / 2.
    row, col = np.divmod(np.arange(len(L)), 255)
    x, y = (col - 127) / 2, (127 - row) / 2
    in_face = np.zeros(len(L), bool)
    if kind == "parallel":
        # Rays in the side-face planes x, y = +-20: measure zero, either one-sided limit.
        in_face = ((np.abs(x) == 20) | (np.abs(y) == 20)) & (np.abs(x) <= 20) & (np.abs(y) <= 20)
        assert in_face.sum() == 4 * 81 - 4
        # And the grid really contains x = 0 and x = +-20.
        assert np.any(x == 0) and np.any(x == 20) and np.any(x == -20)
    assert check_lengths(L, ref, in_face, atol=1e-9 * 1250) == 0


# --------------------------------------------------------------------------------------------
# Lattice polyhedra: rays exactly through vertices and edges


def rays_through(v, edges, origins, directions):
    """Rays passing exactly through a vertex, and through the interior of an edge, of a mesh.

    Everything is integer and decided exactly: a ray ``o + t d`` (``t > 0``) passes through
    vertex ``a`` when ``(a - o) x d = 0`` and ``(a - o) . d > 0``; through the open edge
    ``(a, b)`` when ``d = alpha (a - o) + beta (b - o)`` with ``alpha, beta > 0``. A float
    test preselects the (ray, edge) pairs that can be coplanar; Python integers decide them.

    Returns
    -------
    vertex, edge : (n,) bool
    """
    v = np.asarray(v, np.int64)
    o = np.asarray(origins, np.int64)
    d = np.asarray(directions, np.int64)
    assert np.abs(v).max() + np.abs(o).max() < 2**30 and np.abs(d).max() < 2**31
    vertex = np.zeros(len(o), bool)
    for a in v:
        p = a - o
        vertex |= np.all(np.cross(p, d) == 0, axis=1) & (np.einsum("ij,ij->i", p, d) > 0)
    edge = np.zeros(len(o), bool)
    df = d.astype(float)
    for ia, ib in np.asarray(edges):
        p, q = v[ia] - o, v[ib] - o
        pf, qf = p.astype(float), q.astype(float)
        det = np.einsum("ij,ij->i", pf, np.cross(qf, df))
        size = (np.linalg.norm(pf, axis=1) * np.linalg.norm(qf, axis=1)
                * np.linalg.norm(df, axis=1))
        for k in np.flatnonzero(np.abs(det) <= 1e-9 * size):
            P, Q, D = (x[k].tolist() for x in (p, q, d))
            n = _cross(P, Q)
            if n == [0, 0, 0] or _dot(n, D) != 0:
                continue
            if _dot(_cross(D, Q), n) > 0 and _dot(_cross(P, D), n) > 0:
                edge[k] = True
    return vertex, edge


def _cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _edges(faces):
    e = np.sort(np.asarray(faces)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(e, axis=0)


def _aim_point_source(v, faces, rng, u, distance):
    """Source and detector (beam along -z) putting a chosen vertex ``v0`` on the central ray.

    Returns ``(source, center, pitch, v0)`` in the mesh's frame, all integers. The detector
    is ``2 D0`` from the source (``D0``: the source's height above ``v0``), with pitch ``2 u``:
    its rays cross the plane of ``v0`` exactly on the lattice of spacing ``u`` around it. For
    an edge ``(v0, b)`` with ``b`` nearer the source, the ray through the lattice point
    ``v0 + (b - v0)_xy`` meets the edge at ``t = D0 / (D0 + (b - v0)_z)``, strictly inside it;
    ``v0`` is chosen among the vertices having such an edge (on the lattice, not along the
    beam), preferring those near the middle of the body across the beam (a smaller detector).
    """
    edges = _edges(faces)
    good = []
    for k in range(len(v)):
        nb = np.concatenate([edges[edges[:, 0] == k, 1], edges[edges[:, 1] == k, 0]])
        e = v[nb] - v[k]
        ok = (e[:, 2] > 0) & np.any(e[:, :2] != 0, axis=1) & np.all(e[:, :2] % u == 0, axis=1)
        if ok.any():
            good.append(k)
    assert good, "no vertex with an edge towards the source"
    reach = [np.abs(v[:, :2] - v[k, :2]).max() for k in good]
    best = [good[i] for i in np.argsort(reach, kind="stable")[:3]]
    v0 = v[int(rng.choice(best))]
    d0 = int(distance + rng.integers(-20, 21) * u)
    source = v0 + np.array([0, 0, d0])
    return source, v0 - np.array([0, 0, d0]), 2 * u, v0


def lattice_case(seed, *, kind, offset=(0, 0, 0), distance=1000, scale=1.0, sliver=False,
                 degenerate=False, rays_across=48):
    """A random lattice polyhedron (rational rotation), randomly translated, and a detector
    whose rays pass exactly through chosen vertices and edge points.

    Returns ``(scene, ref, amb, through_vertex, through_edge)``: the exact chords, the rays
    whose length is ambiguous (in a face plane), and how many rays pass exactly through a
    vertex and through the interior of an edge (counted exactly, all vertices and edges).
    """
    rng = np.random.default_rng(seed)
    v, faces = lattice_hull(rng)
    unit = 1
    if sliver or degenerate:
        v, faces = _refine(v, faces, rng, sliver=sliver, degenerate=degenerate)
        unit = 512                      # rays still through the original lattice points
        distance *= 1024
    planes = face_planes(v, faces)
    span = int(np.abs(v).max()) + 2 * unit
    u = unit * max(1, (span // unit) // rays_across)       # ray spacing at the body
    if kind == "parallel":
        # Rays on the lattice of spacing u through v0 (all lattice points when u == unit),
        # the beam axis a few rays away from the body's middle.
        v0 = v[rng.integers(len(v))]
        axis = v0[:2] % u + u * rng.integers(-3, 4, size=2)
        source = np.array([axis[0], axis[1], distance])
        center = np.array([axis[0], axis[1], -span - 5])
        pitch = u
        reach = np.abs(v[:, :2] - axis).max(axis=0) / u
    else:
        source, center, pitch, v0 = _aim_point_source(v, faces, rng, u, distance)
        # Half-extent of the body's projection, in rays, across the beam.
        depth = source[2] - v[:, 2]
        reach = (np.abs(v[:, :2] - v0[:2]) * (source[2] - v0[2]) / depth[:, None]).max(axis=0) / u
    nx, ny = (int(np.ceil(r)) + 1 for r in reach)
    shape = (2 * nx + 3, 2 * ny + 1)
    # A random translation of the whole set-up (integers: exact in float), plus the case's.
    off = np.asarray(offset, np.int64) + rng.integers(-1000, 1001, size=3) * \
        (100 if np.any(offset) else 1)
    mesh = trimesh.Trimesh((v + off) * scale, faces, process=False)
    scene = make_scene(mesh, source=(source + off) * scale, center=(center + off) * scale,
                       shape=shape, pitch=pitch * scale, kind=kind)
    # Reference, in the mesh's frame (a translation does not change chords).
    o, d, t_max = integer_rays(source, center, shape, pitch, kind)
    ref, amb = exact_chords(planes, o, d, t_max, box=(v.min(0) - 1, v.max(0) + 1))
    ref = ref * np.linalg.norm(d, axis=1) * scale
    vertex, edge = rays_through(v, _edges(faces), o, d)
    return scene, ref, amb, int(vertex.sum()), int(edge.sum())


def _refine(v, faces, rng, *, sliver, degenerate):
    """Scale by 1024 (exact) and add slivers or a zero-area T-junction triangle."""
    v = v * 1024
    faces = [list(f) for f in faces]
    verts = v.tolist()
    if sliver:
        for k in rng.choice(len(faces), size=min(6, len(faces)), replace=False):
            a, b, c = faces[k]
            A, B, C = np.array(verts[a]), np.array(verts[b]), np.array(verts[c])
            p = (A + B) // 2 + (C - A) // 1024         # ~1/1000 of the face away from edge ab
            verts.append(p.tolist())
            m = len(verts) - 1
            faces[k] = [a, b, m]
            faces += [[b, c, m], [c, a, m]]
    if degenerate:
        # Split edge (a, b) of face 0 on its neighbour side only and close the T-junction with
        # the zero-area triangle (b, a, m).
        a, b, c = faces[0]
        nb = next(k for k, f in enumerate(faces)
                  if k > 0 and any(f[i] == b and f[(i + 1) % 3] == a for i in range(3)))
        f = faces[nb]
        i = next(i for i in range(3) if f[i] == b and f[(i + 1) % 3] == a)
        d = f[(i + 2) % 3]
        verts.append(((np.array(verts[a]) + np.array(verts[b])) // 2).tolist())
        m = len(verts) - 1
        faces[nb] = [b, m, d]
        faces += [[m, a, d], [b, a, m]]
    return np.array(verts, np.int64), np.array(faces)


CASES = {
    "parallel": dict(kind="parallel"),
    "point": dict(kind="point"),
    "far-source-1e5": dict(kind="point", distance=100_000),
    "offset-1e6": dict(kind="parallel", offset=(1_000_000, -1_000_000, 500_000)),
    "offset-1e6-point": dict(kind="point", offset=(1_000_000, -1_000_000, 500_000)),
    # ~1e-3 mm bodies (power-of-two scale: exact) seen from a source 1000 mm away.
    "tiny-1e-3": dict(kind="parallel", scale=2.0 ** -17, distance=1000 * 2 ** 17),
    "tiny-1e-3-point": dict(kind="point", scale=2.0 ** -17, distance=1000 * 2 ** 17),
    "slivers": dict(kind="parallel", sliver=True),
    "slivers-point": dict(kind="point", sliver=True),
    "zero-area": dict(kind="parallel", degenerate=True),
    "zero-area-point": dict(kind="point", degenerate=True),
}


@functools.lru_cache(maxsize=32)
def _case(name, seed):
    return lattice_case(seed, **CASES[name])          # shared by both engines (read only)


def _run_case(name, seed, engine):
    scene, ref, amb, through_vertex, through_edge = _case(name, seed)
    L = xray_viz.render(scene, engine=engine).total_path_length.ravel()
    size = float(np.ptp(scene.bodies[0].vertices, axis=0).max())
    t_far = float(np.linalg.norm(scene.source.position - scene.detector.center))
    atol = 1e-9 * size + 1e-13 * t_far
    bad = check_lengths(L, ref, amb, atol=atol)
    assert ref.max() > 0
    assert bad == 0, f"{name} seed {seed} engine {engine}: {bad} rays miscounted"
    # Both beams: rays exactly through vertices and through edge points, by construction.
    assert through_vertex > 0 and through_edge > 0, (name, seed, through_vertex, through_edge)
    return through_vertex, through_edge


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("name", sorted(CASES))
def test_lattice_polyhedra_sample(name, engine):
    _run_case(name, 1, engine)


@pytest.mark.slow
@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("name", sorted(CASES))
def test_lattice_polyhedra_many_seeds(name, engine):
    for seed in range(2, 12):
        _run_case(name, seed, engine)


# --------------------------------------------------------------------------------------------
# Any rays (not a detector grid) aimed exactly at vertices and edge points: the NumPy engine


def _aimed_rays(seed, *, offset=0):
    """Rays of random directions through every vertex and every edge midpoint of a random
    lattice polyhedron (doubled, so that midpoints are integers), each continuing into the
    body towards a random interior lattice point. Exact in float."""
    rng = np.random.default_rng(seed)
    v, faces = lattice_hull(rng)
    v2 = 2 * v
    planes = face_planes(v2, faces)
    inside = []
    while len(inside) < 8:
        c = rng.integers(-4, 5, size=3)
        if all(sum(n[i] * int(c[i]) for i in range(3)) < k for n, k in planes):
            inside.append(c)
    edges = _edges(faces)
    targets = np.vstack([v2, v2[edges[:, 0]] // 2 + v2[edges[:, 1]] // 2])
    kinds = np.array(["vertex"] * len(v2) + ["edge"] * len(edges))
    aim = np.array(inside)[rng.integers(len(inside), size=len(targets))]
    d = aim - targets
    back = rng.integers(1, 4, size=len(targets))
    o = targets - back[:, None] * d
    off = rng.integers(-1000, 1001, size=3) * (1 + offset)
    mesh = trimesh.Trimesh((v2 + off).astype(float), faces, process=False)
    return mesh, planes, o, d, back, off, kinds, (v2.min(0) - 1, v2.max(0) + 1)


@pytest.mark.parametrize("seed", [1, 2])
def test_any_rays_through_vertices_and_edge_points_cross_once(seed):
    _check_aimed(seed)


@pytest.mark.slow
@pytest.mark.parametrize("offset", [0, 1000])
def test_any_rays_through_vertices_and_edge_points_many_seeds(offset):
    for seed in range(3, 23):
        _check_aimed(seed, offset=offset)


def _check_aimed(seed, offset=0):
    from xray_viz.tracing import trace_rays

    mesh, planes, o, d, back, off, kinds, box = _aimed_rays(seed, offset=offset)
    scene = make_scene(mesh)
    hits = trace_rays(scene, (o + off).astype(float), d.astype(float))
    n = len(o)
    counts = np.bincount(hits.ray, minlength=n)
    entries = np.bincount(hits.ray, weights=hits.entering, minlength=n).astype(int)
    bad = (counts != 2) | (entries != 1)
    assert not bad.any(), (f"seed {seed}: {np.count_nonzero(bad)} rays miscounted "
                           f"({sorted(set(kinds[bad]))})")
    assert {"vertex", "edge"} <= set(kinds)
    first = np.searchsorted(hits.ray, np.arange(n))
    assert np.all(hits.entering[first]) and not np.any(hits.entering[first + 1])
    # Entry exactly at the aimed point (t = back), the chord against exact arithmetic.
    np.testing.assert_allclose(hits.t[first], back, rtol=1e-12)
    ref, amb = exact_chords(planes, o, d, [10**6] * n, box=box)
    norm = np.linalg.norm(d, axis=1)
    L = (hits.t[first + 1] - hits.t[first]) * norm
    assert not amb.any() and np.all(ref > 0)
    np.testing.assert_allclose(L, ref * norm, rtol=0, atol=1e-9 * np.ptp(box, axis=0).max())


# --------------------------------------------------------------------------------------------
# Many nested shells


def _nested_case(seed, n_shells, kind):
    rng = np.random.default_rng(seed)
    v, faces = lattice_hull(rng, half=3)
    meshes = [trimesh.Trimesh((v * k).astype(float), faces, process=False)
              for k in range(n_shells, 0, -1)]                  # outermost first
    span = int(np.abs(v).max()) * n_shells + 2
    pitch = max(1, span // 40)
    shape = (2 * (span // pitch) + 1, 2 * (span // pitch) + 1)
    source, center = np.array([0, 0, 20 * span]), np.array([0, 0, -span - 5])
    scene = make_scene(meshes, source=source, center=center, shape=shape, pitch=pitch, kind=kind)
    o, d, t_max = integer_rays(source, center, shape, pitch, kind)
    norm = np.linalg.norm(d, axis=1)
    chords, ambs = [], []
    for k in range(n_shells, 0, -1):
        planes = [(n, c * k) for n, c in face_planes(v, faces)]
        ref, amb = exact_chords(planes, o, d, t_max, box=(v.min(0) * k - 1, v.max(0) * k + 1))
        chords.append(ref * norm)
        ambs.append(amb)
    return scene, chords, np.any(ambs, axis=0)


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_many_nested_shells(engine, kind):
    n_shells = 8
    scene, chords, amb = _nested_case(5, n_shells, kind)
    L = xray_viz.render(scene, engine=engine).path_length.reshape(-1, n_shells)
    for k in range(n_shells):
        # Innermost wins: body k holds its chord minus the chord of the shell inside it.
        inner = chords[k + 1] if k + 1 < n_shells else 0.0
        expect = chords[k] - inner
        ok = np.abs(L[:, k] - expect) <= 1e-9 * np.abs(chords[0]).max()
        assert np.all(ok | amb), f"shell {k}: {np.count_nonzero(~(ok | amb))} rays wrong"
    assert np.abs(L.sum(axis=1) - chords[0])[~amb].max() <= 1e-9 * chords[0].max()
