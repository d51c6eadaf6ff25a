"""Checking and repairing meshes so that they can be traced.

The tracer sums signed hit distances along each ray (entries count ``-t``, exits ``+t``), so a
body must be *closed* (watertight: every edge shared by exactly two faces) and *outward*
(consistently wound, positive signed volume). One missing or extra hit is an error of a whole
ray length, not a small one.

* :func:`check_mesh` is fast (trimesh properties only) and is run on every body at load time.
* :func:`repair_mesh` runs the pymeshlab pipeline of FIELD-NOTES section 7: merge duplicate and
  close vertices, remove duplicate and zero-area faces and unreferenced vertices, split
  non-manifold edges, drop tiny stray components, fix non-manifold vertices, close holes, orient
  faces coherently and outward.
* :func:`ensure_traceable` is what the scene loader calls: unchanged when the mesh is already
  closed and outward, repaired (with the list of what changed) otherwise, refused with a
  :class:`~xray_viz.errors.MeshError` when repair does not make it closed.

pymeshlab is imported only inside :func:`repair_mesh`, so a clean mesh costs nothing.

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

from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from xray_viz.errors import MeshError

__all__ = [
    "MeshReport", "RepairReport", "MeshRepairWarning", "check_mesh", "repair_mesh",
    "ensure_traceable", "format_reports", "remember_check",
]


class MeshRepairWarning(UserWarning):
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
        Connected pieces (trimesh ``body_count``).
    volume : float
        Signed volume in mm^3 (positive when the normals point outward).
    outward : bool
        ``winding_consistent and volume > 0``.
    changes : tuple of str
        What a repair changed to arrive at this mesh (empty for a plain check).
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

    @property
    def traceable(self) -> bool:
        """Closed and outward: what the tracer needs."""
        return self.watertight and self.outward

    def problems(self) -> list[str]:
        """Short descriptions of what keeps the mesh from being traceable."""
        out = []
        if not self.watertight:
            out.append(f"not watertight ({self.boundary_edges} boundary edges)")
        if not self.winding_consistent:
            out.append("inconsistent face winding")
        elif self.volume <= 0:
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


def check_mesh(mesh) -> MeshReport:
    """Report whether a mesh is closed and outward, using trimesh's cheap properties.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The mesh to check (not modified).

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
    try:
        key = (id(mesh), hash(mesh))          # trimesh's hash follows the vertex and face data
    except TypeError:
        key = None
    report = _CHECKED.get(key) if key is not None else None
    if report is None:
        report = _check_mesh(mesh)
        if key is not None:
            _CHECKED[key] = report
            while len(_CHECKED) > _CHECKED_SIZE:
                _CHECKED.popitem(last=False)
    return report


def remember_check(mesh, report: MeshReport) -> None:
    """Record ``report`` as :func:`check_mesh`'s answer for ``mesh`` as it is now.

    For a mesh derived from a checked one by a map known to keep the checked properties (an
    orientation-preserving affine transform: see :meth:`xray_viz.scene.Scene.transform_bodies`).
    """
    try:
        key = (id(mesh), hash(mesh))
    except TypeError:
        return
    _CHECKED[key] = report
    while len(_CHECKED) > _CHECKED_SIZE:
        _CHECKED.popitem(last=False)


#: Reports of recently checked meshes: every new Scene checks its bodies, and a viewer or a
#: benchmark that builds a Scene per frame from the same meshes should not pay for it again.
_CHECKED: "OrderedDict[tuple, MeshReport]" = OrderedDict()
_CHECKED_SIZE = 64


def _check_mesh(mesh) -> MeshReport:
    import trimesh

    faces = np.asarray(mesh.faces, dtype=np.int64)
    if len(faces):
        edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        boundary = len(trimesh.grouping.group_rows(edges, require_count=1))
        with np.errstate(all="ignore"):  # a flat mesh: zero volume, NaN centre of mass
            volume = float(mesh.volume)
        components = int(mesh.body_count)
    else:
        boundary, volume, components = 0, 0.0, 0
    watertight = bool(mesh.is_watertight) if len(faces) else False
    winding = bool(mesh.is_winding_consistent) if len(faces) else False
    return MeshReport(
        faces=len(faces), vertices=len(mesh.vertices), watertight=watertight,
        winding_consistent=winding, boundary_edges=boundary, components=components,
        volume=volume, outward=winding and volume > 0,
    )


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
    """
    def fmt(value):
        if isinstance(value, bool):
            return "yes" if value else "no"
        if isinstance(value, float):
            return f"{value:.6g}"
        return str(value)

    rows = [("faces", "faces"), ("vertices", "vertices"), ("watertight", "watertight"),
            ("winding consistent", "winding_consistent"), ("boundary edges", "boundary_edges"),
            ("components", "components"), ("outward", "outward"), ("volume (mm^3)", "volume")]
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


def _orient_outward(vertices, faces):
    """Flip every inside-out component that is not a cavity of another component."""
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(faces))
    parts = [np.flatnonzero(labels == k) for k in range(labels.max() + 1)] if len(faces) else []
    if len(parts) <= 1:
        with np.errstate(all="ignore"):
            negative = len(faces) and mesh.volume < 0
        if negative:
            return faces[:, ::-1].copy()
        return faces
    tris = vertices[faces]
    boxes = [(tris[p].reshape(-1, 3).min(0), tris[p].reshape(-1, 3).max(0)) for p in parts]
    faces = faces.copy()
    for k, part in enumerate(parts):
        sub = trimesh.Trimesh(vertices, faces[part], process=False)
        with np.errstate(all="ignore"):
            negative = sub.volume < 0
        if not negative:
            continue
        lo, hi = boxes[k]
        inside_other = any(np.all(lo >= b[0]) and np.all(hi <= b[1]) and j != k
                           for j, b in enumerate(boxes))
        if inside_other:
            continue  # a cavity: inward normals are right
        faces[part] = faces[part][:, ::-1]
    return faces


def repair_mesh(mesh, *, max_hole_edges: int = 1000, min_component_faces: int = 25,
                merge_distance: float = 0.01):
    """Repair a mesh with pymeshlab so that it is closed and outward.

    The steps, in order (FIELD-NOTES section 7): remove duplicate vertices and merge close ones;
    remove duplicate faces, zero-area faces and unreferenced vertices; split non-manifold edges
    and drop stray components smaller than ``min_component_faces`` (a fin, debris); repair
    non-manifold vertices; close holes; orient faces coherently; flip inside-out components.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The mesh to repair (not modified).
    max_hole_edges : int, optional
        Largest hole, in boundary edges, that is closed.
    min_component_faces : int, optional
        Pieces with fewer faces are removed, unless the mesh has no bigger piece.
    merge_distance : float, optional
        Vertices closer than this percentage of the bounding box diagonal are merged.

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

    def delta(n, noun):
        return f"{'+' if n > 0 else '-'}{abs(n)} {noun}" if n else ""

    def step(label, filter_name, **kwargs):
        v0, f0 = counts()
        result = getattr(ms, filter_name)(**kwargs)
        v1, f1 = counts()
        if (v0, f0) != (v1, f1):
            parts = ", ".join(p for p in (delta(v1 - v0, "vertices"), delta(f1 - f0, "faces")) if p)
            changes.append(f"{label(result) if callable(label) else label} ({parts})")
        return result

    step("removed duplicate vertices", "meshing_remove_duplicate_vertices")
    step("merged close vertices", "meshing_merge_close_vertices",
         threshold=pymeshlab.PercentageValue(merge_distance))
    step("removed duplicate faces", "meshing_remove_duplicate_faces")
    step("removed zero-area faces", "meshing_remove_null_faces")
    ms.meshing_remove_unreferenced_vertices()
    step("split non-manifold edges", "meshing_repair_non_manifold_edges", method="Split Vertices")
    largest = _largest_component_faces(ms)
    if largest >= min_component_faces:
        step("removed small stray components",
             "meshing_remove_connected_component_by_face_number",
             mincomponentsize=min_component_faces, removeunref=True)
    step("split non-manifold vertices", "meshing_repair_non_manifold_vertices")
    ms.meshing_remove_unreferenced_vertices()
    step(lambda r: f"closed {r.get('closed_holes', '?')} holes", "meshing_close_holes",
         maxholesize=int(max_hole_edges))
    faces_before = ms.current_mesh().face_matrix().astype(np.int64)
    ms.meshing_re_orient_faces_coherently()
    m = ms.current_mesh()
    vertices, faces = m.vertex_matrix().astype(np.float64), m.face_matrix().astype(np.int64)
    faces = _orient_outward(vertices, faces)
    if faces.shape == faces_before.shape:
        n_flip = int(np.sum(np.any(_canonical(faces) != _canonical(faces_before), axis=1)))
        if n_flip == len(faces):
            changes.append(f"turned the inside-out mesh outward (flipped all {n_flip} faces)")
        elif n_flip:
            changes.append(f"re-oriented {n_flip} faces outward")
    repaired = trimesh.Trimesh(vertices, faces, process=False)
    after = check_mesh(repaired)
    after = MeshReport(**{**after.__dict__, "changes": tuple(changes)})
    return repaired, RepairReport(before=before, after=after, changes=tuple(changes))


def _canonical(faces):
    """Rotate each triangle so its smallest index comes first (keeps the winding)."""
    k = np.argmin(faces, axis=1)
    idx = (k[:, None] + np.arange(3)) % 3
    return np.take_along_axis(faces, idx, axis=1)


def _largest_component_faces(ms) -> int:
    import trimesh

    m = ms.current_mesh()
    faces = m.face_matrix()
    if len(faces) == 0:
        return 0
    tm = trimesh.Trimesh(m.vertex_matrix(), faces, process=False)
    labels = trimesh.graph.connected_component_labels(tm.face_adjacency, node_count=len(faces))
    return int(np.bincount(labels).max())


def ensure_traceable(body_mesh, *, name: str = "body", repair: bool = True):
    """Return a closed, outward version of a body's mesh, repairing it when needed.

    Parameters
    ----------
    body_mesh : trimesh.Trimesh
        The body's mesh in scene coordinates.
    name : str, optional
        The body's name, for messages.
    repair : bool, optional
        When False, a mesh that needs repair is refused instead.

    Returns
    -------
    mesh : trimesh.Trimesh
        ``body_mesh`` itself when it was already traceable, otherwise the repaired mesh.
    changes : list of str
        What was fixed; empty when nothing was.

    Raises
    ------
    MeshError
        The mesh is not traceable and ``repair`` is False, or repair did not make it closed
        and outward.

    Examples
    --------
    >>> import trimesh
    >>> ball = trimesh.creation.icosphere(subdivisions=2, radius=10.0)
    >>> mesh, changes = ensure_traceable(ball, name="ball")
    >>> mesh is ball, changes
    (True, [])
    """
    report = check_mesh(body_mesh)
    if report.traceable:
        return body_mesh, []
    problems = "; ".join(report.problems())
    if not repair:
        raise MeshError(f"body {name!r}: mesh is {problems}; fix the file (e.g. `xray-viz mesh "
                        "IN -o OUT`) or allow repair at load time (repair = true)")
    repaired, rep = repair_mesh(body_mesh)
    if not rep.after.traceable:
        raise MeshError(f"body {name!r}: mesh is {problems} and automatic repair failed (still "
                        f"{'; '.join(rep.after.problems())}); close the surface in a mesh editor")
    changes = [f"was {problems}"] + list(rep.changes)
    return repaired, changes
