"""Reading triangle meshes from files."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from xray_viz._files import require_regular
from xray_viz.errors import MeshError, SceneFileNotFoundError, excerpt, one_line, \
    reader_reason

__all__ = ["load_mesh", "MESH_SUFFIXES", "as_trimesh", "scene_nodes", "expand_nodes"]

#: File suffixes read by :func:`load_mesh` through trimesh.
TRIMESH_SUFFIXES = (".stl", ".obj", ".ply", ".off", ".glb", ".gltf")
#: File suffixes read through VTK's readers: XML PolyData, UnstructuredGrid and StructuredGrid,
#: and legacy VTK (any dataset). A dataset that is not a surface (tetrahedra, hexahedra, a
#: structured grid) becomes its boundary surface, triangulated.
VTK_SUFFIXES = (".vtp", ".vtu", ".vts", ".vtk")

#: The VTK reader class of each suffix: (module, class).
_VTK_READERS = {
    ".vtp": ("vtkmodules.vtkIOXML", "vtkXMLPolyDataReader"),
    ".vtu": ("vtkmodules.vtkIOXML", "vtkXMLUnstructuredGridReader"),
    ".vts": ("vtkmodules.vtkIOXML", "vtkXMLStructuredGridReader"),
    ".vtk": ("vtkmodules.vtkIOLegacy", "vtkDataSetReader"),
}
#: Scene formats whose nodes become one body each (unless ``merge = true``).
NODE_SUFFIXES = (".glb", ".gltf")
#: Every file suffix read by :func:`load_mesh`.
MESH_SUFFIXES = TRIMESH_SUFFIXES + VTK_SUFFIXES


def _quiet_vtk_read(pv, path: Path):
    """Read a VTK file with VTK's own logging silenced; its first error becomes a MeshError.

    On a corrupt file VTK prints a screenful (its logger, its output window, and pyvista's
    observer passing it on to Python logging and warnings) before the reader gives up. Here a
    plain VTK reader runs (no pyvista observer), VTK's logger is off
    (``pv.vtk_verbosity('off')``) and the output window is swapped for a string buffer, so the
    user sees one line.
    """
    from vtkmodules.vtkCommonCore import vtkOutputWindow, vtkStringOutputWindow

    import importlib

    module, name = _VTK_READERS[path.suffix.lower()]
    Reader = getattr(importlib.import_module(module), name)
    buffer = vtkStringOutputWindow()
    previous = vtkOutputWindow.GetInstance()
    vtkOutputWindow.SetInstance(buffer)
    try:
        with pv.vtk_verbosity("off"):
            reader = Reader()
            reader.SetFileName(str(path))
            reader.Update()
            output = reader.GetOutputDataObject(0)
    except Exception as exc:
        raise MeshError(f"{path}: cannot read mesh: {_reason(exc)}") from None
    finally:
        vtkOutputWindow.SetInstance(previous)
    errors = _vtk_errors(buffer.GetOutput())
    if errors or output is None:
        reason = errors[0] if errors else "the VTK reader produced nothing"
        raise MeshError(f"{path}: cannot read mesh (corrupt or not a {path.suffix} file): "
                        f"{one_line(reason)}")
    return pv.wrap(output)


def _shorten_quotes(text: str) -> str:
    """Replace every quoted stretch of ``text`` (a reader's message quoting a line of the file,
    which may be any file a scene names) by ``'...'`` (:func:`~xray_viz.errors.reader_reason`).

    Examples
    --------
    >>> _shorten_quotes("could not convert string to float: 'FAKESECRET-1'")
    "could not convert string to float: '...'"
    """
    return reader_reason(text, limit=len(text) + 10)


def _reason(exc: BaseException) -> str:
    """A reader's exception as a short, escaped part of one line: readers quote file contents
    (a line of a corrupt file, a whole binary header), so quoted stretches are cut to 40
    characters, control characters escaped and the whole cut to 160 characters. Its type is
    named when the message alone says nothing (a ``KeyError`` prints just the missing key)."""
    text = one_line(_shorten_quotes(one_line(str(exc), limit=2000)), limit=160)
    if isinstance(exc, FileNotFoundError):
        return f"it refers to a file that does not exist: {excerpt(text, 80)}"
    if not text or isinstance(exc, (KeyError, IndexError, AttributeError, TypeError, NameError,
                                    OSError)):
        return f"{type(exc).__name__}" + (f": {text}" if text else "")
    return text


#: VTK messages reworded: (a regular expression, what to say instead).
_VTK_REWORDING = (
    (re.compile(r"^Unrecognized file type: (.*?)(?: for file: .*)?$", re.S),
     lambda m: ("not a legacy VTK header: its first lines are not '# vtk DataFile Version "
                "x.y', a title, ASCII or BINARY")),
    (re.compile(r"did not create output .*REQUEST_DATA_OBJECT", re.S),
     lambda m: "its header names no dataset type VTK can read (a line such as "
               "'DATASET POLYDATA')"),
)


def _vtk_errors(text) -> list[str]:
    """The messages of VTK's ``ERROR: In file, line N`` / ``vtkClass (0x...): message`` blocks,
    and of its warnings that report a read error (a truncated binary file is only a
    "Generic Warning: ... Error reading binary data!"), errors first.

    VTK's string output window hands back ``bytes`` when a message quotes bytes that are not
    UTF-8 (a binary file read as a legacy header): they are decoded with escapes. Messages
    are reworded where VTK's own words do not help (:data:`_VTK_REWORDING`), stripped of
    object addresses, and quote at most a short escaped excerpt of the file."""
    if isinstance(text, bytes):
        text = text.decode("utf-8", errors="backslashreplace")
    errors, warnings = [], []
    lines = text.splitlines()
    for k, line in enumerate(lines):
        if k + 1 >= len(lines) or not (line.startswith("ERROR") or "Warning" in line):
            continue
        message = lines[k + 1]
        message = (message.split("): ", 1)[1] if "): " in message else message).strip()
        message = re.sub(r"\s*\(0x[0-9a-fA-F]+\)", "", message)
        for pattern, say in _VTK_REWORDING:
            match = pattern.search(message)
            if match:
                message = say(match)
                break
        if line.startswith("ERROR"):
            errors.append(one_line(message, limit=160))
        elif re.search(r"error|premature|eof|cannot|unable", message, re.I):
            warnings.append(one_line(message, limit=160))
    return errors + warnings


def _read_vtk(path: Path):
    """(vertices, faces) of a VTK file (:data:`VTK_SUFFIXES`), triangulated; a volume mesh
    (tetrahedra, hexahedra) becomes its boundary surface; pyvista imported only here."""
    try:
        import pyvista as pv
    except ImportError:  # pragma: no cover - pyvista is a dependency
        raise MeshError(f"{path}: reading {path.suffix} files needs pyvista "
                        "(pip install pyvista)") from None
    data = _quiet_vtk_read(pv, path)
    if not isinstance(data, pv.PolyData):
        try:
            data = data.extract_surface(algorithm="dataset_surface")
        except TypeError:  # older pyvista: no algorithm keyword
            data = data.extract_surface()
        except Exception as exc:
            raise MeshError(f"{path}: not a surface mesh and no surface could be extracted "
                            f"({type(data).__name__}): {_reason(exc)}") from None
    if data.n_cells and not data.is_all_triangles:
        data = data.triangulate()
    if data.faces.size == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    faces = np.asarray(data.regular_faces, dtype=np.int64)
    return np.asarray(data.points, dtype=np.float64), faces


def load_mesh(path: str | Path, *, process: bool = True):
    """Read a triangle mesh.

    Parameters
    ----------
    path : str or Path
        An STL (ASCII or binary), OBJ, PLY, OFF or GLB/GLTF file (read with trimesh), or a
        VTK ``.vtp``, ``.vtu``, ``.vts`` or legacy ``.vtk`` file (read with VTK's readers
        through pyvista, imported only for these; polygons are triangulated, and a volume
        mesh, such as a tetrahedral ``.vtu``, is reduced to its boundary surface).
        ``model.glb#NODE`` is the mesh of one node of a glTF/GLB scene (its transform
        applied); ``model.glb`` alone is every node's mesh merged.
    process : bool, optional
        Merge coincident duplicate vertices (trimesh ``process=True``; STL stores every
        triangle's corners separately, a triangle soup). False gives the vertices and faces
        as stored, for a report of the file itself (``xray-viz mesh``).

    Returns
    -------
    trimesh.Trimesh
        With duplicate vertices merged unless ``process`` is False.

    Raises
    ------
    SceneFileNotFoundError
        The file does not exist.
    MeshError
        The file cannot be read, holds no triangles, or has NaN or infinite vertices.

    Examples
    --------
    >>> import tempfile, pathlib, trimesh
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "box.stl"
    >>> _ = trimesh.creation.box(extents=[10, 10, 10]).export(path)
    >>> mesh = load_mesh(path)
    >>> len(mesh.faces), len(mesh.vertices), mesh.is_watertight
    (12, 8, True)
    """
    import trimesh

    path = Path(path)
    if not path.exists():
        base, node = split_node(path)
        if node is not None:
            return _node_mesh(base, node, process=process)
    if not path.exists():
        raise SceneFileNotFoundError(f"{path}: mesh file not found")
    require_regular(path, MeshError, "mesh file")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise MeshError(f"{path}: unsupported mesh format {path.suffix!r} "
                        f"(use one of {', '.join(MESH_SUFFIXES)})")
    stl = _read_binary_stl(path) if path.suffix.lower() == ".stl" else None
    if stl is not None:               # trimesh's arrays, read without its loader
        vertices, faces = stl
    elif path.suffix.lower() in VTK_SUFFIXES:
        vertices, faces = _read_vtk(path)
    else:
        try:
            loaded = trimesh.load(path, force="mesh", process=False)
        except Exception as exc:  # trimesh raises many types on corrupt files
            raise MeshError(f"{path}: cannot read mesh: {_reason(exc)}") from None
        vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
        faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if len(faces) == 0 or len(vertices) == 0:
        raise MeshError(f"{path}: mesh is empty (no triangles)")
    if not np.all(np.isfinite(vertices)):
        bad = int(np.sum(~np.all(np.isfinite(vertices), axis=1)))
        raise MeshError(f"{path}: {bad} vertices are NaN or infinite")
    if stl is not None and process:    # trimesh's vertex merge, the same arrays, faster
        vertices, faces = _merge_soup(vertices, faces)
        mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False, validate=False)
        mesh.metadata["processed"] = True
        return mesh
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=bool(process),
                           validate=False)
    return mesh


#: One triangle of a binary STL file: normal, three corners, two attribute bytes.
_STL_RECORD = np.dtype([("normals", "<f4", (3,)), ("vertices", "<f4", (3, 3)),
                        ("attributes", "<u2")])


def _read_binary_stl(path: Path):
    """``(vertices, faces)`` of a binary STL file as ``trimesh.load(path, process=False)``
    gives them (every triangle's three corners in file order, as float64; faces
    ``0 1 2, 3 4 5, ...``), or None when trimesh would not read it as binary (its size does
    not match the face count of its 84-byte header: an ASCII file) or it holds no triangle;
    then trimesh reads it."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    if len(data) < 84:
        return None
    n = int.from_bytes(data[80:84], "little")
    if n == 0 or len(data) - 84 != n * _STL_RECORD.itemsize:
        return None
    corners = np.frombuffer(data, dtype=_STL_RECORD, offset=84)["vertices"]
    return (corners.reshape(-1, 3).astype(np.float64),
            np.arange(3 * n, dtype=np.int64).reshape(-1, 3))


def _merge_soup(vertices, faces):
    """Duplicate vertices merged as trimesh's ``merge_vertices`` (``process=True``) merges
    them, bit for bit: vertices equal once rounded to ``trimesh.tol.merge`` are one, kept in
    the order of their first use, at the position of that first use. For a mesh whose every
    vertex is used by a face (an STL soup); one lexicographic sort instead of trimesh's sort of
    rows as bytes (~4x faster).

    Examples
    --------
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0], [0, 0, 0], [0, 0, 1.]])
    >>> merged, faces = _merge_soup(v, np.arange(6).reshape(2, 3))
    >>> merged.tolist(), faces.tolist()
    ([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], [[0, 1, 2], [1, 0, 3]])
    """
    import trimesh

    digits = trimesh.util.decimal_to_digits(trimesh.tol.merge)
    rows = (vertices * (10 ** digits)).round().astype(np.int64)     # trimesh's rounding
    order = np.lexsort(rows.T[::-1])           # stable: each group starts at its first use
    ranked = rows[order]
    start = np.empty(len(rows), bool)
    start[:1] = True
    np.any(ranked[1:] != ranked[:-1], axis=1, out=start[1:])
    first = order[start]
    by_use = np.argsort(first)
    label = np.empty(len(first), np.int64)
    label[by_use] = np.arange(len(first))
    inverse = np.empty(len(rows), np.int64)
    inverse[order] = label[np.cumsum(start) - 1]
    return vertices[first[by_use]], inverse[faces.reshape(-1)].reshape(-1, 3)


def as_trimesh(mesh):
    """A body's mesh as a ``trimesh.Trimesh``: a pyvista dataset becomes its extracted,
    triangulated surface; anything else is returned as it is (``Body`` checks it).

    Examples
    --------
    >>> import pyvista as pv
    >>> ball = as_trimesh(pv.Sphere(radius=2.0))
    >>> type(ball).__name__, ball.is_watertight
    ('Trimesh', True)
    >>> type(as_trimesh(pv.ImageData(dimensions=(3, 3, 3)))).__name__  # any dataset: its surface
    'Trimesh'
    """
    import sys

    pv = sys.modules.get("pyvista")   # not imported: the mesh cannot be one of its datasets
    if pv is None or not isinstance(mesh, pv.DataSet):
        return mesh
    import trimesh

    if isinstance(mesh, pv.PolyData):
        surface = mesh
    else:
        try:
            surface = mesh.extract_surface(algorithm="dataset_surface")
        except TypeError:  # older pyvista: no algorithm keyword
            surface = mesh.extract_surface()
    if surface.n_cells and not surface.is_all_triangles:
        surface = surface.triangulate()
    faces = (np.asarray(surface.regular_faces, dtype=np.int64) if surface.faces.size
             else np.zeros((0, 3), np.int64))
    return trimesh.Trimesh(np.asarray(surface.points, dtype=np.float64), faces, process=True,
                           validate=False)


def scene_nodes(path) -> list[str]:
    """Names of the nodes of a glTF/GLB file that carry a mesh (sorted); [] for other files.

    Examples
    --------
    >>> import tempfile, pathlib, trimesh
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "two.glb"
    >>> s = trimesh.Scene()
    >>> _ = s.add_geometry(trimesh.creation.box(), node_name="box")
    >>> _ = s.add_geometry(trimesh.creation.icosphere(), node_name="ball")
    >>> _ = s.export(path)
    >>> scene_nodes(path)
    ['ball', 'box']
    """
    path = Path(path)
    if path.suffix.lower() not in NODE_SUFFIXES or not path.is_file():
        return []
    scene = _load_scene(path)
    return sorted(scene.graph.nodes_geometry)


def split_node(path) -> tuple[Path, str | None]:
    """``FILE#NODE`` split on the first ``#`` after which the part before it is an existing
    glTF/GLB file: ``(FILE, NODE)``; else ``(path, None)``. A node's name may hold ``/``
    (``Armature/Bone``) and ``#``; so may the folders before the file.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> folder = pathlib.Path(tempfile.mkdtemp()) / "a#b"
    >>> folder.mkdir()
    >>> _ = (folder / "model.glb").write_bytes(b"")
    >>> f, node = split_node(f"{folder}/model.glb#Armature/Bone#2")
    >>> f == folder / "model.glb", node
    (True, 'Armature/Bone#2')
    >>> split_node(folder / "model.glb")[1] is None
    True
    """
    text = str(path)
    start = 0
    while (k := text.find("#", start)) >= 0:
        base = Path(text[:k])
        if base.suffix.lower() in NODE_SUFFIXES and base.is_file():
            return base, text[k + 1:]
        start = k + 1
    return Path(path), None


def _load_scene(path: Path):
    import trimesh

    try:
        return trimesh.load(path, force="scene", process=False)
    except Exception as exc:  # trimesh raises many types on corrupt files
        raise MeshError(f"{path}: cannot read mesh: {_reason(exc)}") from None


def _node_mesh(path: Path, node: str, *, process: bool):
    import trimesh

    scene = _load_scene(path)
    nodes = sorted(scene.graph.nodes_geometry)
    if node not in nodes:
        raise MeshError(f"{path}: has no mesh node {excerpt(node)}; its nodes: "
                        f"{', '.join(nodes) or 'none'}")
    transform, geometry = scene.graph[node]
    mesh = scene.geometry[geometry].copy()
    mesh.apply_transform(transform)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if len(faces) == 0:
        raise MeshError(f"{path}#{node}: mesh is empty (no triangles)")
    if not np.all(np.isfinite(vertices)):
        raise MeshError(f"{path}#{node}: vertices are NaN or infinite")
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=bool(process), validate=False)


def expand_nodes(raw_bodies, base_dir, *, file=None):
    """The scene file's ``[[body]]`` tables with each glTF/GLB of several mesh nodes expanded
    into one table per node (``mesh = "model.glb#NODE"``, ``name = "NAME/NODE"``, NAME being
    the table's name or else the file's stem), unless the table says ``merge = true`` (then
    one body of every node's mesh). ``merge`` is removed from the tables returned.

    Examples
    --------
    >>> expand_nodes([{"name": "a", "mesh": "a.stl", "mu": 0.1}], ".")
    [{'name': 'a', 'mesh': 'a.stl', 'mu': 0.1}]
    """
    from xray_viz.errors import SceneError

    if not isinstance(raw_bodies, list):
        return raw_bodies
    out = []
    for k, raw in enumerate(raw_bodies):
        if not isinstance(raw, dict):
            out.append(raw)
            continue
        raw = dict(raw)
        merge = raw.pop("merge", False)
        where = f"{file}: " * bool(file) + f"[[body]] #{k + 1}"
        if not isinstance(merge, bool):
            raise SceneError(f"{where} merge must be true or false, got {excerpt(str(merge))}")
        mesh = raw.get("mesh")
        if merge or not isinstance(mesh, str) or Path(mesh).suffix.lower() not in NODE_SUFFIXES:
            out.append(raw)
            continue
        path = Path(mesh) if Path(mesh).is_absolute() else Path(base_dir) / mesh
        nodes = scene_nodes(path) if path.is_file() else []
        if len(nodes) < 2:
            out.append(raw)
            continue
        prefix = raw.get("name") if isinstance(raw.get("name"), str) else Path(mesh).stem
        for node in nodes:
            out.append({**raw, "name": f"{prefix}/{node}", "mesh": f"{mesh}#{node}"})
    return out
