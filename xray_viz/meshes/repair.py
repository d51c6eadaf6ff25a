"""Checking and repairing meshes so that they can be traced.

The tracer sums signed hit distances along each ray (entries count ``-t``, exits ``+t``), so a
body must be *closed* (watertight: every edge shared by exactly two faces) and *outward*
(consistently wound, positive signed volume). One missing or extra hit is an error of a whole
ray length, not a small one.

A body of several closed pieces (edge-connected: pieces touching at a vertex are separate) is
the region where the **winding number** of its surface is **positive** (the nonzero rule):
along a ray, each entry into an outward piece adds one, each exit subtracts one, and the ray
is in the material wherever the count is above zero. Both engines trace it so. Hence:

* outward pieces add material: overlapping outward pieces give their union, and an outward
  piece inside another is redundant (it changes nothing), not a cavity;
* an inward-facing (negative volume) piece wholly inside an outward piece carves a cavity
  (a hollow shell); overlapping cavities carve their union; an outward piece inside a cavity
  is an island of material again;
* an inward piece inside no outward piece is an inside-out solid: :func:`check_mesh` flags it
  and repair flips it outward (the scene loader warns, naming the body);
* an inward piece crossing the surface of an outward piece (partly inside, partly outside) is
  ambiguous - a cavity biting into the solid, or an inside-out solid joined to it - and is
  refused with a :class:`~xray_viz.errors.MeshError`: fix it in a mesh editor;
* a mesh that is inside-out as a whole (negative total volume, and turning every piece over
  leaves no inward piece outside an outward one: an inside-out ball, an inside-out hollow
  shell) is turned over as a whole.

Containment is tested with a few face centres of each inward piece, by ray parity against
each outward piece whose bounding box overlaps (sort and sweep on the boxes): near-linear in
the number of pieces.

* :func:`check_mesh` is fast (trimesh properties, plus a few inside/outside ray tests for
  the inward pieces of a closed mesh of several pieces) and is run on every body at load time.
* :func:`repair_mesh` runs the pymeshlab pipeline of FIELD-NOTES section 7: merge duplicate and
  close vertices, remove duplicate and zero-area faces and unreferenced vertices, split
  non-manifold edges, drop small open debris (never a closed piece), fix non-manifold vertices,
  close holes, orient faces coherently (each piece as most of its faces were) and turn
  inside-out pieces outward (see above).
* :func:`ensure_traceable` is what the scene loader calls: unchanged when the mesh is already
  closed and outward, repaired (with the list of what changed) otherwise, refused with a
  :class:`~xray_viz.errors.MeshError` when repair does not make it closed.

The self-intersection test of :func:`check_mesh` is pymeshlab's, run by a compiled kernel
(``meshes/_check_kernels.py``, vcglib's arithmetic in its order, so the faces that pymeshlab
selects in a new process) once that is compiled, by pymeshlab itself until then. (pymeshlab's
own answer can change within one process: after a few calls of its coherent re-orientation or
hole closing it tests each pair of faces differently; the kernel's answer does not change.)

Examples
--------
>>> import trimesh
>>> from xray_viz.meshes.repair import check_mesh, repair_mesh
>>> ball = trimesh.creation.icosphere(subdivisions=2, radius=10.0)
>>> check_mesh(ball).traceable
True
>>> inside_out = trimesh.Trimesh(ball.vertices, ball.faces[:, ::-1], process=False)
>>> check_mesh(inside_out).outward
False
>>> fixed, report = repair_mesh(inside_out)
>>> check_mesh(fixed).traceable, report.changes
(True, ('turned the inside-out mesh outward (flipped all 320 faces)',))
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from xray_viz import progress as _progress
from xray_viz.errors import MeshError

__all__ = [
    "MeshReport", "RepairReport", "MeshWarning", "MeshRepairWarning", "check_mesh", "repair_mesh",
    "ensure_traceable", "format_reports", "simple_winding",
    "self_intersecting_faces", "surfaces_cross", "body_inside", "containers",
]


class MeshWarning(UserWarning):
    """Something about a body's mesh that the user should know (it is still traced right)."""


class MeshRepairWarning(MeshWarning):
    """A body's mesh was not closed or not outward and was repaired at load time."""


@dataclass(frozen=True)
class MeshReport:
    """What a tracer needs to know about a triangle mesh.

    Attributes
    ----------
    faces, vertices : int
        Number of triangles and of vertices.
    watertight : bool
        Every edge is shared by exactly two faces (trimesh ``is_watertight``).
    winding_consistent : bool
        Neighbouring faces are wound the same way (trimesh ``is_winding_consistent``).
    boundary_edges : int
        Edges used by exactly one face (the rims of holes).
    components : int
        Edge-connected pieces (faces joined across shared edges; pieces touching only at a
        vertex are separate).
    volume : float
        Signed volume in mm^3 (positive when the normals point outward).
    outward : bool
        ``winding_consistent``, ``volume > 0``, not ``flat``, and no inside-out or crossing
        piece (``misoriented == crossing == 0``).
    changes : tuple of str
        What a repair changed to arrive at this mesh (empty for a plain check).
    misoriented : int
        Pieces that repair turns outward (see :func:`check_mesh`): inward pieces inside no
        outward piece (an inside-out ball beside a good one), or every piece when the mesh is
        inside-out as a whole. 0 for a single piece (then ``volume < 0`` says inside-out).
    flat : bool
        The enclosed volume is zero (to rounding): a sheet, or faces folded onto each other.
    crossing : int
        Inward pieces partly inside and partly outside the outward pieces: ambiguous, not
        repairable.
    simple : bool
        The winding number is provably 0 or 1 everywhere: one piece whose surface does not pass
        through itself, or such outward pieces with pairwise disjoint bounding boxes (the fast
        engine's one-body signed sum is exact then).
    self_intersections : int or None
        None when not checked (a mesh that is not closed, consistently wound and solid).
        Faces that cross another face of their own piece (the surface passes through itself:
        two lobes overlapping inside one skin, a cap folded through the opposite side). Such a
        body is traced by the nonzero winding rule in every engine (material wherever the
        surface winds around a point at least once), never by the signed depth sum.
    """

    faces: int
    vertices: int
    watertight: bool
    winding_consistent: bool
    boundary_edges: int
    components: int
    volume: float
    outward: bool
    changes: tuple[str, ...] = ()
    misoriented: int = 0
    flat: bool = False
    crossing: int = 0
    simple: bool = False
    self_intersections: int | None = 0

    @property
    def traceable(self) -> bool:
        """Closed and outward: what the tracer needs."""
        return self.watertight and self.outward

    def problems(self) -> list[str]:
        """Short descriptions of what keeps the mesh from being traceable."""
        out = []
        if not self.watertight:
            out.append(f"not watertight ({self.boundary_edges} boundary edges)"
                       if self.boundary_edges else
                       "not watertight (edges shared by more than two faces)")
        if not self.winding_consistent:
            out.append("inconsistent face winding")
        elif self.flat:
            out.append("flat (zero volume)")
        elif self.crossing:
            out.append(_crossing_text(self.crossing, self.components))
        elif 0 < self.misoriented < self.components:
            out.append(f"inside-out in {self.misoriented} of {self.components} pieces (facing "
                       "inward but inside no outward piece, so not a cavity)")
        elif self.volume < 0 or self.misoriented:
            out.append("inside-out (negative volume)")
        return out


@dataclass(frozen=True)
class RepairReport:
    """The mesh before and after :func:`repair_mesh`, and what was changed.

    Attributes
    ----------
    before, after : MeshReport
    changes : tuple of str
        One entry per step that changed something, e.g. ``"closed 2 holes (+14 faces)"``.
    """

    before: MeshReport
    after: MeshReport
    changes: tuple[str, ...] = field(default=())

    def table(self) -> str:
        """The before/after report as an aligned text table."""
        return format_reports([("before", self.before), ("after", self.after)], changes=self.changes)


def check_mesh(mesh, *, cache: bool = True) -> MeshReport:
    """Report whether a mesh is closed and outward, using trimesh's cheap properties.

    A closed mesh of several pieces is read by the nonzero rule (see the module docstring):
    each inward piece is tested for lying inside the outward pieces. One inside none is
    inside-out (:attr:`MeshReport.misoriented`), one partly inside is ambiguous
    (:attr:`MeshReport.crossing`); outward pieces are never wrong, whatever their nesting.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The mesh to check (not modified).
    cache : bool, optional
        Read and keep the report on disk by content hash (the mesh's arrays and the checking
        code: ``xray_viz.meshes._report_cache``), so that loading the same mesh again costs
        a hash instead of the checks (seconds for a million faces). ``XRAY_VIZ_CACHE_DIR=off``
        turns it off everywhere.

    Returns
    -------
    MeshReport

    Examples
    --------
    >>> import trimesh
    >>> report = check_mesh(trimesh.creation.box(extents=[10, 20, 30]))
    >>> report.watertight, report.outward, round(report.volume)
    (True, True, 6000)
    """
    if not cache:
        return _check_mesh(mesh)
    from xray_viz.meshes import _report_cache

    try:
        key = _report_cache.mesh_key(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    except (TypeError, ValueError):          # not arrays of numbers: the check's message
        return _check_mesh(mesh)
    report = _report_cache.load(key, MeshReport)
    if report is None:
        report = _check_mesh(mesh)
        _report_cache.store(key, report)
    return report


def _check_mesh(mesh) -> MeshReport:
    faces = np.asarray(mesh.faces, dtype=np.int64)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    from xray_viz.meshes import _check_kernels

    # the self-intersection test's grid, built on another thread while this one finds the
    # edge facts and the volume that say whether the test is needed (None: not started)
    started = _check_kernels.start_grid(vertices, faces)
    try:
        if len(faces):
            boundary, watertight, winding, labels, components = _edge_facts(faces,
                                                                            len(vertices))
            volume = _volume(vertices, faces)
        else:
            boundary, volume, components = 0, 0.0, 0
            watertight = winding = False
        flat = _is_flat(vertices, volume) if len(faces) else True
        misoriented = crossing = 0
        self_crossing = None                 # not checked: only a closed surface is tested
        simple = components == 1
        if watertight and winding and components > 1:
            # pieces may cancel (an inside-out copy beside a good one): not flat then
            nest = _nesting(vertices, faces, labels, components)
            flat = _is_flat(vertices, float(np.abs(nest.volume).sum()))
            misoriented, crossing = int(nest.flip.sum()), int(nest.crossing.sum())
            simple = nest.simple
        if watertight and winding and not flat:
            self_crossing = _self_crossing_faces(vertices, faces, labels, components,
                                                 started=started)
            started = None
            simple = simple and self_crossing == 0
    finally:
        if started is not None:
            _check_kernels.discard(started)
    return MeshReport(
        faces=len(faces), vertices=len(mesh.vertices), watertight=watertight,
        winding_consistent=winding, boundary_edges=boundary, components=components,
        volume=volume, outward=(winding and volume > 0 and not flat and misoriented == 0
                                and crossing == 0),
        misoriented=misoriented, flat=flat, crossing=crossing, simple=simple,
        self_intersections=self_crossing,
    )


def _edge_facts(faces, n_vertices):
    """``(boundary, watertight, winding, labels, n_pieces)`` of a face array, from one sort of
    its edges: trimesh's answers (``group_rows`` of the sorted edges, ``is_watertight``,
    ``is_winding_consistent``, the connected components of ``face_adjacency``), computed once.

    An edge used by one face is a boundary edge; the mesh is watertight when every edge is
    used by exactly two faces; the winding is consistent when each edge used by two faces is
    traversed in opposite directions by them; two faces sharing an edge used by exactly two
    faces are in the same piece.

    The compiled ``edge_facts`` of ``meshes/_check_kernels.py`` answers the same, once it is
    compiled (as :func:`self_intersecting_faces`).
    """
    from xray_viz.meshes import _check_kernels

    if _check_kernels.is_ready() and (faces.min() >= 0 and faces.max() < n_vertices):
        return _check_kernels.edge_facts(faces, n_vertices)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    directed = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    lo = np.minimum(directed[:, 0], directed[:, 1])
    hi = np.maximum(directed[:, 0], directed[:, 1])
    key = lo * np.int64(max(n_vertices, 1)) + hi
    order = np.argsort(key)        # the order within an edge's uses does not matter below
    ks = key[order]
    first = np.empty(len(ks), bool)
    first[0] = True
    np.not_equal(ks[1:], ks[:-1], out=first[1:])
    starts = np.flatnonzero(first)
    counts = np.diff(np.append(starts, len(ks)))
    boundary = int((counts == 1).sum())
    pairs = starts[counts == 2]
    a, b = order[pairs], order[pairs + 1]            # the two uses of each two-face edge
    watertight = bool(len(pairs) * 2 == len(directed))
    winding = bool(np.array_equal(directed[a, 1], directed[b, 0]))
    fa, fb = a // 3, b // 3
    n = len(faces)
    graph = coo_matrix((np.ones(len(fa), np.int8), (fa, fb)), shape=(n, n))
    count, labels = connected_components(graph, directed=False)
    return boundary, watertight, winding, np.asarray(labels, np.int64), int(count)


def _volume(vertices, faces) -> float:
    """Enclosed volume (trimesh's ``mass_properties`` integral, its volume term only: the same
    arithmetic, so the same float). The coordinates are gathered one column at a time rather
    than as (m, 3, 3) triangles: 9 arrays of m floats instead of one of 9 m (0.06 s instead of
    0.16-0.3 s at 1.3M faces), the same numbers; the compiled checks do it in one pass, once
    they are ready (``_check_kernels.volume``: 0.05 s -> 0.01 s at 1.3M faces)."""
    from xray_viz.meshes import _check_kernels

    V = np.asarray(vertices)
    F = np.asarray(faces)
    if _check_kernels.is_ready():
        try:
            return _check_kernels.volume(V, F)
        except IndexError:            # a face index out of range: as NumPy answers below
            pass
    x, y, z = (np.ascontiguousarray(V[:, k]) for k in range(3))
    i0, i1, i2 = (np.ascontiguousarray(F[:, k]) for k in range(3))
    y0, y1, y2 = y[i0], y[i1], y[i2]
    z0, z1, z2 = z[i0], z[i1], z[i2]
    cross_x = (y1 - y0) * (z2 - z1) - (z1 - z0) * (y2 - y1)
    f1 = x[i0] + x[i1] + x[i2]
    with np.errstate(all="ignore"):
        return float(np.sum(cross_x * f1) / 6.0)


def self_intersecting_faces(vertices, faces, *, pieces=None) -> np.ndarray:
    """Which faces cross another face of the same triangle set: pymeshlab's
    ``compute_selection_by_self_intersections_per_face`` (vcglib's triangle-triangle test;
    faces sharing an edge are not tested against each other, faces sharing one vertex only
    by the opposite edge).

    The compiled kernel of ``meshes/_check_kernels.py`` gives the faces pymeshlab selects in a
    new process (the same arithmetic); pymeshlab itself runs while that kernel is neither compiled in this
    process nor in numba's cache (compiling it costs more than pymeshlab on any mesh below
    a few million faces).

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (m, 3) int
    pieces : (m,) int, optional
        A label per face: then only faces crossing a face of the same label count.

    Returns
    -------
    (m,) bool

    Examples
    --------
    >>> import numpy as np, trimesh
    >>> a = trimesh.creation.box(extents=[2, 2, 2])
    >>> b = a.copy(); _ = b.apply_translation([1, 0.5, 0.25])
    >>> both = trimesh.util.concatenate([a, b])
    >>> int(self_intersecting_faces(a.vertices, a.faces).sum()), bool(
    ...     self_intersecting_faces(both.vertices, both.faces).any())
    (0, True)
    >>> pieces = np.repeat([0, 1], 12)
    >>> bool(self_intersecting_faces(both.vertices, both.faces, pieces=pieces).any())
    False
    """
    from xray_viz.meshes import _check_kernels

    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) < 2:
        return np.zeros(len(faces), bool)
    vertices = np.asarray(vertices, dtype=np.float64)
    if _check_kernels.is_ready() and np.isfinite(vertices).all():
        return _check_kernels.self_intersections(vertices, faces, pieces)
    if pieces is None:
        return _pymeshlab_self_intersections(vertices, faces)
    pieces = np.asarray(pieces, dtype=np.int64).reshape(-1)
    return _self_crossing_pymeshlab(np.asarray(vertices, dtype=np.float64), faces, pieces)


def _pymeshlab_self_intersections(vertices, faces) -> np.ndarray:
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.asarray(vertices, dtype=np.float64),
                               face_matrix=np.asarray(faces).astype(np.int32)))
    ms.compute_selection_by_self_intersections_per_face()
    return np.asarray(ms.current_mesh().face_selection_array(), dtype=bool)


def _self_crossing_faces(vertices, faces, labels, n_pieces, *, started=None) -> int:
    """Faces that cross a face of their own piece (crossings between pieces do not count:
    overlapping pieces are a union by the nonzero rule). ``started``: the compiled test's
    grid, from ``_check_kernels.start_grid``."""
    pieces = labels if n_pieces > 1 else None
    if started is not None:
        from xray_viz.meshes import _check_kernels

        return int(_check_kernels.self_intersections(vertices, faces, pieces,
                                                     started=started).sum())
    return int(self_intersecting_faces(vertices, faces, pieces=pieces).sum())


def _self_crossing_pymeshlab(vertices, faces, labels) -> np.ndarray:
    """:func:`self_intersecting_faces` with ``pieces`` by pymeshlab: the whole set first,
    then the flagged pieces again in groups whose bounding boxes are pairwise disjoint (a
    greedy colouring of the box-overlap graph): within a group only a piece's own faces can
    meet, so one call per group finds the crossings within pieces."""
    flagged = _pymeshlab_self_intersections(vertices, faces)
    _, labels = np.unique(labels, return_inverse=True)
    n_pieces = int(labels.max()) + 1 if len(labels) else 0
    if not flagged.any() or n_pieces < 2:
        return flagged
    pieces = np.unique(labels[flagged])
    tri = vertices[faces]
    lo = np.full((n_pieces, 3), np.inf)
    hi = np.full((n_pieces, 3), -np.inf)
    np.minimum.at(lo, labels, tri.min(axis=1))
    np.maximum.at(hi, labels, tri.max(axis=1))
    mask = np.zeros(n_pieces, bool)
    mask[pieces] = True
    i, j = _box_pairs(lo, hi, mask, mask)
    neighbours = {int(p): set() for p in pieces}
    for a, b in zip(i.tolist(), j.tolist()):
        neighbours[a].add(b)
    colour = {}
    for p in sorted(neighbours, key=lambda q: -len(neighbours[q])):
        used = {colour[q] for q in neighbours[p] if q in colour}
        colour[p] = next(c for c in range(len(used) + 1) if c not in used)
    out = np.zeros(len(faces), bool)
    for c in set(colour.values()):
        group = np.isin(labels, np.array([p for p, k in colour.items() if k == c]))
        out[group] = _pymeshlab_self_intersections(vertices, faces[group])
    return out


def _face_boxes(mesh):
    """``(vertices, faces, low corners, high corners)`` of a mesh's faces."""
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    tri = v[f]
    return v, f, tri.min(axis=1), tri.max(axis=1)


def _faces_near(boxes, lo, hi):
    """(vertices, faces) of the faces (of :func:`_face_boxes` ``boxes``) whose bounding boxes
    meet the box [lo, hi]."""
    v, f, tlo, thi = boxes
    pad = 1e-9 * float(np.linalg.norm(np.asarray(hi) - np.asarray(lo)))
    meet = np.all((tlo <= np.asarray(hi) + pad) & (thi >= np.asarray(lo) - pad), axis=1)
    return v, f[meet]


def surfaces_cross(mesh_a, mesh_b, *, bounds=None, self_intersecting=None) -> bool:
    """Whether a face of one mesh meets a face of the other (the surfaces cross or touch).

    Only faces near the other mesh's bounding box are tested (pymeshlab's triangle-triangle
    test on the two sets together; a crossing within one mesh alone does not count).

    Parameters
    ----------
    mesh_a, mesh_b : trimesh.Trimesh
    bounds : ((lo, hi), (lo, hi)), optional
        The meshes' bounding boxes, when known.
    self_intersecting : (bool, bool), optional
        Whether each mesh crosses itself (:attr:`MeshReport.self_intersections`), when known.

    Examples
    --------
    >>> import trimesh
    >>> big = trimesh.creation.box(extents=[10, 10, 10])
    >>> small = trimesh.creation.box(extents=[2, 2, 2])
    >>> poking = small.copy(); _ = poking.apply_translation([4.5, 0, 0])
    >>> surfaces_cross(small, big), surfaces_cross(poking, big)
    (False, True)
    """
    return _surfaces_cross(mesh_a, mesh_b, bounds, self_intersecting,
                           (_face_boxes(mesh_a), _face_boxes(mesh_b)))


def _surfaces_cross(mesh_a, mesh_b, bounds, self_intersecting, boxes) -> bool:
    """:func:`surfaces_cross` with the meshes' :func:`_face_boxes` ``boxes`` (a pair)."""
    (alo, ahi), (blo, bhi) = bounds if bounds is not None else (
        _bounds(mesh_a), _bounds(mesh_b))
    va, fa = _faces_near(boxes[0], blo, bhi)
    vb, fb = _faces_near(boxes[1], alo, ahi)
    if not len(fa) or not len(fb):
        return False
    vertices = np.concatenate([va, vb])
    faces = np.concatenate([fa, fb + len(va)])
    flagged = self_intersecting_faces(vertices, faces)
    if not flagged.any():
        return False
    if self_intersecting is None:
        self_intersecting = (check_mesh(mesh_a).self_intersections,
                             check_mesh(mesh_b).self_intersections)
    if not any(self_intersecting):
        return True
    alone = np.concatenate([self_intersecting_faces(va, fa), self_intersecting_faces(vb, fb)])
    return bool(np.any(flagged & ~alone))


def body_inside(mesh_a, mesh_b) -> bool:
    """Whether closed mesh ``a`` lies wholly inside closed mesh ``b``: the surfaces do not
    cross (:func:`surfaces_cross`) and a point of every piece of ``a`` is inside ``b``
    (winding number > 0). Exact: no sampling vote.

    Examples
    --------
    >>> import trimesh
    >>> big = trimesh.creation.icosphere(radius=10.0)
    >>> small = trimesh.creation.icosphere(radius=3.0)
    >>> moved = small.copy(); _ = moved.apply_translation([8.0, 0, 0])   # pokes out of big
    >>> body_inside(small, big), body_inside(moved, big), body_inside(big, small)
    (True, False, False)
    """
    from xray_viz.tracing.hits import inside_counts

    faces = np.asarray(mesh_a.faces, dtype=np.int64)
    if not len(faces) or not len(mesh_b.faces):
        return False
    tris = np.asarray(mesh_b.vertices, dtype=np.float64)[np.asarray(mesh_b.faces)]
    if not np.all(inside_counts(tris, _piece_points(mesh_a)) > 0):   # cheap: most pairs end here
        return False
    return not surfaces_cross(mesh_a, mesh_b)


def _piece_points(mesh) -> np.ndarray:
    """(pieces, 3) float: the centre of the first face of each edge-connected piece."""
    labels, _ = _piece_labels(mesh)
    first = np.unique(labels, return_index=True)[1]
    v = np.asarray(mesh.vertices, dtype=np.float64)
    return v[np.asarray(mesh.faces, dtype=np.int64)[first]].mean(axis=1)


def _bounds(mesh):
    v = np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3)
    return (v.min(axis=0), v.max(axis=0)) if len(v) else (np.full(3, np.inf), np.full(3, -np.inf))


def containers(meshes, *, bounds=None, reports=None, cache: bool = True) -> list[list[int]]:
    """For each closed mesh, the indices of the meshes it lies wholly inside
    (:func:`body_inside`), tested only where its bounding box is inside theirs, with one
    inside/outside trace per containing candidate.

    Parameters
    ----------
    meshes : sequence of trimesh.Trimesh
    bounds : (n, 2, 3) float, optional
        Their bounding boxes, when known.
    reports : sequence of MeshReport, optional
        Their :func:`check_mesh` reports, when known.
    cache : bool, optional
        Read and keep each pair's answer on disk by the two meshes' content hashes, as
        :func:`check_mesh` keeps reports (``XRAY_VIZ_CACHE_DIR``; the answer depends only on
        the two meshes): loading the same scene again tests nothing (the frog's 16 bodies:
        0.27 s).

    Examples
    --------
    >>> import trimesh
    >>> big = trimesh.creation.box(extents=[20, 20, 20])
    >>> small = trimesh.creation.box(extents=[4, 4, 4])
    >>> poking = small.copy(); _ = poking.apply_translation([9, 0, 0])
    >>> containers([small, big, poking])
    [[1], [], []]
    """
    n = len(meshes)
    bbox = [tuple(b) for b in bounds] if bounds is not None else [_bounds(m) for m in meshes]
    crossing = [bool(r.self_intersections) for r in reports] if reports is not None else None
    points = {}
    boxes = {}                                    # face boxes of the meshes tested
    out = [[] for _ in range(n)]
    lo = np.array([bx[0] for bx in bbox], dtype=np.float64).reshape(n, 3)
    hi = np.array([bx[1] for bx in bbox], dtype=np.float64).reshape(n, 3)
    solid = np.array([len(m.faces) > 0 for m in meshes], dtype=bool)
    from xray_viz.meshes import _report_cache

    keys = None
    if cache and (_report_cache.cache_dir() is not None or _report_cache.shipped_pairs()):
        try:
            keys = [_report_cache.mesh_key(np.asarray(m.vertices), np.asarray(m.faces))
                    for m in meshes]
        except (TypeError, ValueError):      # not arrays of numbers: tested, not stored
            keys = None
    for b in range(n):
        if not solid[b]:
            continue
        within = solid & np.all(lo >= lo[b], axis=1) & np.all(hi <= hi[b], axis=1)
        within[b] = False
        cand = np.flatnonzero(within).tolist()          # boxes inside b's box: candidates
        known = {}
        if keys is not None:
            for a in cand:
                flag = _report_cache.load_flag(_report_cache.pair_key(keys[a], keys[b]))
                if flag is not None:
                    known[a] = flag
        todo = [a for a in cand if a not in known]
        found = _inside_of(meshes, b, todo, bbox, crossing, points, boxes)
        for a in todo:
            if keys is not None:
                _report_cache.store_flag(_report_cache.pair_key(keys[a], keys[b]), a in found)
        for a in cand:                                  # in index order, as they were tested
            if known.get(a, a in found):
                out[a].append(b)
    return out


def _inside_of(meshes, b, cand, bbox, crossing, points, boxes) -> set:
    """The meshes ``cand`` (boxes inside ``b``'s) that lie wholly inside mesh ``b``: every
    piece's point inside it (one trace for them all) and no surfaces crossing."""
    from xray_viz.tracing.hits import inside_counts

    found = set()
    if not cand:
        return found
    for a in cand:
        if a not in points:
            points[a] = _piece_points(meshes[a])
    tris = np.asarray(meshes[b].vertices, dtype=np.float64)[np.asarray(meshes[b].faces)]
    inside = inside_counts(tris, np.concatenate([points[a] for a in cand])) > 0
    splits = np.cumsum([len(points[a]) for a in cand])[:-1]
    for a, ok in zip(cand, np.split(inside, splits)):
        if not ok.all():
            continue
        for k in (a, b):
            if k not in boxes:
                boxes[k] = _face_boxes(meshes[k])
        if not _surfaces_cross(
                meshes[a], meshes[b], (bbox[a], bbox[b]),
                None if crossing is None else (crossing[a], crossing[b]),
                (boxes[a], boxes[b])):
            found.add(a)
    return found


def simple_winding(mesh) -> bool:
    """Whether the winding number of a closed mesh is provably 0 or 1 everywhere.

    True for a mesh of one edge-connected piece, or of outward pieces whose bounding boxes
    are pairwise disjoint (:attr:`MeshReport.simple`). Then the signed sum of hit depths along
    a ray is its length inside the body; otherwise the hits must be sorted and the winding
    number tracked (:class:`xray_viz.bodies.Bodies` keeps this per body: :attr:`~xray_viz.bodies.
    Bodies.simple`).

    Parameters
    ----------
    mesh : trimesh.Trimesh

    Returns
    -------
    bool
    """
    return check_mesh(mesh).simple


def _crossing_text(k, n) -> str:
    return (f"{k} of {n} pieces facing inward but crossing the surface of an outward piece "
            "(neither a cavity wholly inside it nor a separate inside-out solid)")


def _diagonal(vertices) -> float:
    """Length of the bounding box's diagonal (0 for no vertices). Column by column: NumPy's
    axis-0 reduction of an (n, 3) array is ~20x slower than three strided 1-d ones (29 ms
    against 1.3 ms at 655k vertices), for the same numbers."""
    if not len(vertices):
        return 0.0
    return float(np.linalg.norm([np.ptp(vertices[:, k]) for k in range(3)]))


def _is_flat(vertices, volume) -> bool:
    """Zero enclosed volume, to rounding, for the size of the mesh."""
    if not len(vertices) or not np.isfinite(volume):
        return True
    diag = _diagonal(vertices)
    return abs(volume) <= 1e-9 * diag ** 3


#: Face centres of each inward piece tested for lying inside the outward pieces.
_SAMPLES = 32


def _piece_labels(mesh):
    """(labels, n): the edge-connected piece of every face of a trimesh."""
    import trimesh

    if len(mesh.faces) == 0:
        return np.zeros(0, np.int64), 0
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency,
                                                      node_count=len(mesh.faces))
    return np.asarray(labels, np.int64), int(labels.max()) + 1


@dataclass(frozen=True)
class _Nesting:
    """What the nonzero rule makes of the pieces of a closed mesh (see :func:`_nesting`).

    Attributes
    ----------
    volume : (n,) float
        Signed volume of each piece.
    flip : (n,) bool
        Pieces to turn over.
    crossing : (n,) bool
        Inward pieces partly inside and partly outside the outward ones: ambiguous.
    simple : bool
        The winding number is provably 0 or 1 everywhere.
    """

    volume: np.ndarray
    flip: np.ndarray
    crossing: np.ndarray
    simple: bool


def _nesting(vertices, faces, labels, n) -> _Nesting:
    """Classify the pieces of a closed, consistently wound mesh by the nonzero rule.

    Outward pieces are always right. An inward piece is a cavity when all its sample points
    (face centres) lie inside some outward piece, inside-out (to flip) when none does, and
    ambiguous (crossing) otherwise. When the total volume is negative and turning every piece
    over leaves every (then) inward piece a cavity, every piece is flipped instead.
    """
    tris = vertices[faces] - vertices.mean(axis=0)  # near the origin: the volume sum stays exact
    six_v = np.einsum("ij,ij->i", tris[:, 0], np.cross(tris[:, 1], tris[:, 2]))
    volume = np.bincount(labels, weights=six_v, minlength=n) / 6.0
    none = np.zeros(n, bool)
    diag = _diagonal(vertices)
    tol = 1e-9 * diag ** 3                            # as _is_flat: zero volume to rounding
    inward, outward = volume < -tol, volume > tol
    if n < 2:
        return _Nesting(volume, inward.copy(), none, True)
    order = np.argsort(labels, kind="stable")
    starts = np.searchsorted(labels[order], np.arange(n + 1))
    corner_lo = tris.min(axis=1)[order]
    corner_hi = tris.max(axis=1)[order]
    lo = np.minimum.reduceat(corner_lo, starts[:-1], axis=0)
    hi = np.maximum.reduceat(corner_hi, starts[:-1], axis=0)
    if not inward.any():
        simple = bool(outward.all()) and not len(_box_pairs(lo, hi, outward, outward)[0])
        return _Nesting(volume, none, none, simple)
    pieces = (tris, labels, order, starts, lo, hi)
    inside, total = _inside_counts(pieces, inward, outward)
    isolated = inward & (inside == 0)
    crossing = inward & (inside > 0) & (inside < total)
    if not (isolated.any() or crossing.any()):
        return _Nesting(volume, none, none, False)
    if volume.sum() < 0:
        # inside-out as a whole? Turned over, the outward pieces become the inward ones
        inside, total = _inside_counts(pieces, outward, inward)
        if np.all(inside[outward] == total[outward]):
            return _Nesting(volume, inward | outward, none, False)
    return _Nesting(volume, isolated & ~crossing, crossing, False)


def _box_pairs(lo, hi, a, b):
    """Pairs ``(i, j)``, ``i`` in mask ``a``, ``j`` in mask ``b``, ``i != j``, whose boxes
    ``[lo, hi]`` overlap (touching counts), by sort and sweep along the axis with the fewest
    overlapping intervals."""
    idx = np.flatnonzero(a | b)
    best = None
    for axis in range(3):
        o = idx[np.argsort(lo[idx, axis], kind="stable")]
        # boxes o[k+1 : stop[k]] start within box o[k]'s interval along this axis
        stop = np.searchsorted(lo[o, axis], hi[o, axis], side="right")
        count = np.maximum(stop - np.arange(len(o)) - 1, 0)
        if best is None or count.sum() < best[2].sum():
            best = (axis, o, count)
    _, o, count = best
    total = int(count.sum())
    first = np.repeat(np.arange(len(o)), count)
    second = first + 1 + np.arange(total) - np.repeat(np.cumsum(count) - count, count)
    i, j = o[first], o[second]
    meet = np.all((lo[i] <= hi[j]) & (lo[j] <= hi[i]), axis=1)
    i, j = np.concatenate([i[meet], j[meet]]), np.concatenate([j[meet], i[meet]])
    keep = a[i] & b[j] & (i != j)
    return i[keep], j[keep]


def _inside_counts(pieces, query, target):
    """For each piece in mask ``query``: how many of its sample points (up to ``_SAMPLES``
    face centres spread over it) lie inside some piece of mask ``target``, and how many were
    tested. Ray parity against each target piece separately (watertight ray-triangle tests, so
    a ray through an edge counts once), so the targets' winding does not matter; only targets
    whose bounding box overlaps the query piece's are traced.

    Returns
    -------
    inside, total : (n,) int
    """
    from xray_viz.tracing.hits import PROBE
    from xray_viz.tracing.hits import trace_triangles

    tris, labels, order, starts, lo, hi = pieces
    n = len(lo)
    size = np.diff(starts)
    total = np.where(query, np.minimum(size, _SAMPLES), 0)
    inside = np.zeros(n, np.int64)
    qi, tj = _box_pairs(lo, hi, query, target)
    if not len(qi):
        return inside, total
    qs = np.unique(qi)
    m = total[qs]
    owner = np.repeat(qs, m)
    k = np.arange(int(m.sum())) - np.repeat(np.cumsum(m) - m, m)
    pos = starts[owner] + (k * (size[owner] - 1)) // np.maximum(total[owner] - 1, 1)
    points = tris[order[pos]].mean(axis=1)
    in_target = np.flatnonzero(np.isin(labels, np.unique(tj)))
    ray, tri, *_ = trace_triangles(tris[in_target], points,
                                   np.broadcast_to(PROBE, points.shape))
    key = np.unique(ray * n + labels[in_target[tri]], return_counts=True)
    odd = key[0][key[1] % 2 == 1] // n          # points inside some target piece
    inside_point = np.zeros(len(points), bool)
    inside_point[odd] = True
    inside += np.bincount(owner[inside_point], minlength=n)
    return inside, total


def format_reports(columns, *, changes=()) -> str:
    """Format one or more :class:`MeshReport` side by side as a text table.

    Parameters
    ----------
    columns : list of (str, MeshReport)
        Column title and report.
    changes : sequence of str, optional
        Listed below the table.

    Examples
    --------
    >>> import trimesh
    >>> print(format_reports([("mesh", check_mesh(trimesh.creation.box()))]))  # doctest: +NORMALIZE_WHITESPACE
                          mesh
    faces                   12
    vertices                 8
    watertight             yes
    winding consistent     yes
    boundary edges           0
    components               1
    outward                yes
    volume (mm^3)            1
    self-intersecting faces  0
    """
    def fmt(value):
        if value is None:
            return "-"
        if isinstance(value, bool):
            return "yes" if value else "no"
        if isinstance(value, float):
            return f"{value:.6g}"
        return str(value)

    rows = [("faces", "faces"), ("vertices", "vertices"), ("watertight", "watertight"),
            ("winding consistent", "winding_consistent"), ("boundary edges", "boundary_edges"),
            ("components", "components"), ("outward", "outward"), ("volume (mm^3)", "volume"),
            ("self-intersecting faces", "self_intersections")]
    cells = [[title for title, _ in columns]]
    cells += [[fmt(getattr(r, attr)) for _, r in columns] for _, attr in rows]
    labels = [""] + [label for label, _ in rows]
    lw = max(len(s) for s in labels)
    widths = [max(len(row[k]) for row in cells) for k in range(len(columns))]
    lines = [f"{label:<{lw}}  " + "  ".join(f"{c:>{w}}" for c, w in zip(row, widths))
             for label, row in zip(labels, cells)]
    if changes:
        lines.append("changes:")
        lines += [f"  - {c}" for c in changes]
    elif len(columns) > 1:
        lines.append("changes: none")
    return "\n".join(line.rstrip() for line in lines)


def _orient_outward(vertices, faces, reference=None):
    """Turn the pieces the nonzero rule needs turned (see :func:`_nesting`).

    With ``reference`` (the same faces before pymeshlab re-oriented them coherently), a piece
    most of whose faces were reversed by that is first turned back: each piece keeps the
    orientation most of its faces had, so a cavity stays a cavity.

    Returns
    -------
    faces : (F, 3) int
        A copy with the faces of those pieces reversed (``faces`` itself when none is).
    flipped : (k,) int
        Indices of the pieces flipped by the nonzero rule.
    n : int
        Number of pieces.
    """
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    labels, n = _piece_labels(mesh)
    if n == 0:
        return faces, np.zeros(0, np.int64), 0
    if reference is not None and reference.shape == faces.shape:
        reversed_ = np.any(_canonical(faces) != _canonical(reference), axis=1)
        back = np.bincount(labels, weights=reversed_, minlength=n) * 2 > np.bincount(labels,
                                                                                  minlength=n)
        if back.any():
            faces = faces.copy()
            sel = back[labels]
            faces[sel] = faces[sel][:, ::-1]
    nest = _nesting(np.asarray(vertices, np.float64), faces, labels, n)
    flipped = np.flatnonzero(nest.flip)
    if not len(flipped):
        return faces, flipped, n
    faces = faces.copy()
    sel = nest.flip[labels]
    faces[sel] = faces[sel][:, ::-1]
    return faces, flipped, n


@_progress.tracked("repairing the mesh", unit="steps")
def repair_mesh(mesh, *, max_hole_edges: int = 1000, min_component_faces: int = 25,
                merge_distance: float = 0.01):
    """Repair a mesh with pymeshlab so that it is closed and outward.

    The steps, in order (FIELD-NOTES section 7): merge duplicate (coincident) vertices, then
    vertices on open edges closer than ``merge_distance``; remove duplicate faces, zero-area
    faces and unreferenced vertices; split non-manifold edges and drop small *open* pieces (a stray fin,
    debris: pieces of fewer than ``min_component_faces`` faces with a boundary or non-manifold
    edge; closed pieces are kept however small); repair non-manifold vertices; close holes;
    orient faces coherently, each piece as most of its faces were; turn outward every inward
    piece that lies inside no outward piece (or the whole mesh, when it is inside-out as a
    whole; see the module docstring). An inward piece crossing another is left as it is (the
    report says so).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The mesh to repair (not modified).
    max_hole_edges : int, optional
        Largest hole, in boundary edges, that is closed.
    min_component_faces : int, optional
        Open pieces with fewer faces are removed, unless the mesh has no bigger piece.
    merge_distance : float, optional
        Vertices on open edges (cracks in the surface) closer than this percentage of the
        bounding box diagonal are merged: an absolute distance, the default 0.01 % is
        0.014 mm for a ball of radius 40 mm. Vertices of closed parts are never merged.

    Returns
    -------
    mesh : trimesh.Trimesh
        The repaired mesh.
    report : RepairReport
        Before and after, and what was changed.

    Examples
    --------
    >>> import trimesh
    >>> ball = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    >>> holed = trimesh.Trimesh(ball.vertices, ball.faces[5:], process=False)
    >>> fixed, report = repair_mesh(holed)
    >>> report.before.watertight, report.after.watertight
    (False, True)
    """
    import pymeshlab
    import trimesh

    before = check_mesh(mesh)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int32)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices, face_matrix=faces))
    changes: list[str] = []

    def counts():
        m = ms.current_mesh()  # count referenced vertices: some filters leave unused ones
        f = m.face_matrix()
        return len(np.unique(f)), len(f)

    def amount(n, noun):
        return f"{'+' if n > 0 else '-'}{abs(n)} {noun}" if n else ""

    def step(label, filter_name, **kwargs):
        """Run a filter (a name, or a function of the MeshSet); when it changed the counts,
        record ``label`` and the change."""
        v0, f0 = counts()
        run = filter_name if callable(filter_name) else getattr(ms, filter_name)
        result = run(**kwargs)
        _progress.advance()
        v1, f1 = counts()
        if (v0, f0) != (v1, f1):
            text = label(result, v1 - v0, f1 - f0) if callable(label) else label
            parts = ", ".join(p for p in (amount(v1 - v0, "vertices"), amount(f1 - f0, "faces"))
                              if p)
            changes.append(f"{text} ({parts})")
        return result

    def merged(what):
        def label(_, dv, df):
            # pymeshlab drops a face whose corners are (now) the same vertex twice
            if dv == 0:
                return f"removed {-df} zero-area faces with a repeated corner"
            text = f"merged {what}"
            if df < 0:
                text += f"; removed {-df} faces left with a repeated corner"
            return text
        return label

    step(merged("coincident duplicate vertices"), "meshing_remove_duplicate_vertices")
    diag = _diagonal(vertices)
    threshold = merge_distance / 100.0 * diag  # an absolute distance in mm, as documented
    if threshold > 0:
        step(merged(f"open-edge vertices closer than {threshold:.3g} mm"),
             lambda: _merge_close_boundary_vertices(ms, pymeshlab, threshold))
    step("removed duplicate faces", "meshing_remove_duplicate_faces")
    step("removed zero-area faces", "meshing_remove_null_faces")
    ms.meshing_remove_unreferenced_vertices()
    step("split non-manifold edges", "meshing_repair_non_manifold_edges", method="Split Vertices")
    removed = _remove_open_debris(ms, pymeshlab, min_faces=min_component_faces)
    if removed:
        n_pieces, n_faces = removed
        changes.append(f"removed {n_pieces} small open pieces, stray faces or debris "
                       f"(-{n_faces} faces)")
    step("split non-manifold vertices", "meshing_repair_non_manifold_vertices")
    ms.meshing_remove_unreferenced_vertices()
    step(lambda r, dv, df: f"closed {r.get('closed_holes', '?')} holes", "meshing_close_holes",
         maxholesize=int(max_hole_edges))
    faces_before = ms.current_mesh().face_matrix().astype(np.int64)
    ms.meshing_re_orient_faces_coherently()
    m = ms.current_mesh()
    vertices, faces = m.vertex_matrix().astype(np.float64), m.face_matrix().astype(np.int64)
    faces, _, _ = _orient_outward(vertices, faces, reference=faces_before)
    if faces.shape == faces_before.shape:
        changes += _orientation_changes(vertices, faces_before, faces)
    repaired = trimesh.Trimesh(vertices, faces, process=False)
    after = check_mesh(repaired)
    after = dataclasses.replace(after, changes=tuple(changes))
    return repaired, RepairReport(before=before, after=after, changes=tuple(changes))


def _orientation_changes(vertices, old, new) -> list[str]:
    """Describe how the winding of ``new`` differs from ``old`` (same faces, some reversed)."""
    import trimesh

    flipped = np.any(_canonical(new) != _canonical(old), axis=1)
    n_flip = int(flipped.sum())
    if n_flip == 0:
        return []
    if n_flip == len(new):
        return [f"turned the inside-out mesh outward (flipped all {n_flip} faces)"]
    labels, n = _piece_labels(trimesh.Trimesh(vertices, new, process=False))
    per_piece = np.bincount(labels, weights=flipped, minlength=n)
    size = np.bincount(labels, minlength=n)
    whole = per_piece == size
    out = []
    if whole.any():
        k = int(whole.sum())
        out.append(f"turned {k} of {n} inside-out pieces outward ({int(size[whole].sum())} "
                   "faces)")
    partly = int(per_piece[~whole].sum())
    if partly:
        out.append(f"re-oriented {partly} faces to agree with their neighbours")
    return out


def _boundary_vertices(faces) -> np.ndarray:
    """Vertices on an edge used by only one face."""
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    unique, uses = np.unique(edges, axis=0, return_counts=True)
    return np.unique(unique[uses == 1])


def _merge_close_boundary_vertices(ms, pymeshlab, threshold):
    """Merge vertices on open edges that lie within ``threshold`` mm of each other.

    This stitches the cracks of a triangle soup whose copies of a corner are a little apart
    (exported in single precision, jittered). Only vertices on open edges are merged: a closed
    surface's short edges (0.004 mm in the decimated frog skeleton) are not collapsed, which
    pymeshlab's ``meshing_merge_close_vertices`` would do, making non-manifold edges.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    m = ms.current_mesh()
    vertices, faces = m.vertex_matrix(), m.face_matrix().astype(np.int64)
    if len(faces) == 0:
        return
    rim = _boundary_vertices(faces)
    if len(rim) < 2:
        return
    pairs = cKDTree(vertices[rim]).query_pairs(threshold, output_type="ndarray")
    if len(pairs) == 0:
        return
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(rim),) * 2)
    _, cluster = connected_components(graph, directed=False)
    first = np.full(cluster.max() + 1, len(rim))
    np.minimum.at(first, cluster, np.arange(len(rim)))
    remap = np.arange(len(vertices))
    remap[rim] = rim[first[cluster]]
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices,
                               face_matrix=remap[faces].astype(np.int32)))
    ms.meshing_remove_unreferenced_vertices()


def _remove_open_debris(ms, pymeshlab, *, min_faces):
    """Remove pieces of fewer than ``min_faces`` faces that are open or non-manifold.

    Closed pieces (every edge shared by exactly two faces of the piece) are kept however small:
    a little bone is not debris. Nothing is removed when no piece has ``min_faces`` faces.

    Returns
    -------
    (pieces, faces) removed, or None when nothing was.
    """
    import trimesh

    m = ms.current_mesh()
    vertices, faces = m.vertex_matrix(), m.face_matrix().astype(np.int64)
    if len(faces) == 0:
        return None
    labels, n = _piece_labels(trimesh.Trimesh(vertices, faces, process=False))
    size = np.bincount(labels, minlength=n)
    if n < 2 or size.max() < min_faces:
        return None
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, inverse, uses = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
    bad_edge = uses[inverse.ravel()] != 2  # boundary (1) or non-manifold (3 or more)
    open_piece = np.bincount(np.repeat(labels, 3), weights=bad_edge, minlength=n) > 0
    drop = open_piece & (size < min_faces)
    if not drop.any():
        return None
    keep = ~drop[labels]
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices,
                               face_matrix=faces[keep].astype(np.int32)))
    ms.meshing_remove_unreferenced_vertices()
    return int(drop.sum()), int((~keep).sum())


def _canonical(faces):
    """Rotate each triangle so its smallest index comes first (keeps the winding)."""
    k = np.argmin(faces, axis=1)
    idx = (k[:, None] + np.arange(3)) % 3
    return np.take_along_axis(faces, idx, axis=1)


def ensure_traceable(body_mesh, *, name: str = "body", repair: bool = True, report=None,
                     return_report: bool = False):
    """Return a closed, outward version of a body's mesh, repairing it when needed.

    Parameters
    ----------
    body_mesh : trimesh.Trimesh
        The body's mesh in scene coordinates.
    name : str, optional
        The body's name, for messages.
    repair : bool, optional
        When False, a mesh that needs repair is refused instead.
    report : MeshReport, optional
        :func:`check_mesh` of ``body_mesh`` when the caller has it (not checked again).
    return_report : bool, optional
        Also return the report of the mesh returned.

    Returns
    -------
    mesh : trimesh.Trimesh
        ``body_mesh`` itself when it was already traceable, otherwise the repaired mesh.
    changes : list of str
        What was fixed; empty when nothing was.
    report : MeshReport
        Of the mesh returned (with ``return_report=True`` only).

    Raises
    ------
    MeshError
        The mesh is not traceable and ``repair`` is False, or repair did not make it closed
        and outward, or an inward piece crosses another piece (no repair can tell a cavity
        biting into the solid from an inside-out solid joined to it).

    Examples
    --------
    >>> import trimesh
    >>> ball = trimesh.creation.icosphere(subdivisions=2, radius=10.0)
    >>> mesh, changes = ensure_traceable(ball, name="ball")
    >>> mesh is ball, changes
    (True, [])
    """
    if report is None:
        report = check_mesh(body_mesh)
    if report.traceable:
        _warn_self_intersections(name, report)
        return (body_mesh, [], report) if return_report else (body_mesh, [])
    if report.crossing:
        raise _crossing_error(name, report)
    problems = "; ".join(report.problems())
    if not repair:
        raise MeshError(f"body {name!r}: mesh is {problems}; fix the file (e.g. `xray-viz mesh "
                        "IN -o OUT`) or allow repair at load time (repair = true)")
    repaired, rep = repair_mesh(body_mesh)
    if rep.after.crossing:
        raise _crossing_error(name, rep.after)
    if not rep.after.traceable:
        raise MeshError(f"body {name!r}: mesh is {problems} and automatic repair failed (still "
                        f"{'; '.join(rep.after.problems())}); close the surface in a mesh editor")
    changes = [f"was {problems}"] + list(rep.changes)
    _warn_self_intersections(name, rep.after)
    return (repaired, changes, rep.after) if return_report else (repaired, changes)


def _warn_self_intersections(name, report) -> None:
    if report.self_intersections:
        import warnings

        warnings.warn(
            f"body {name!r}: the surface passes through itself ({report.self_intersections} "
            "faces cross others of the same piece); traced by the nonzero winding rule, "
            "material wherever the surface winds around a point (overlapping lobes count "
            "once); see `xray-viz mesh FILE`", MeshWarning, stacklevel=3)


def _crossing_error(name, report) -> MeshError:
    return MeshError(
        f"body {name!r}: mesh has {_crossing_text(report.crossing, report.components)}; in a "
        "mesh editor, turn such a piece outward (to add it to the solid) or keep it wholly "
        "inside the outward piece (to carve a cavity)")
