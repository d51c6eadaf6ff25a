"""Reading triangle meshes from files."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from xray_viz.errors import MeshError, SceneFileNotFoundError

__all__ = ["load_mesh", "MESH_SUFFIXES"]

#: File suffixes read by :func:`load_mesh` through trimesh.
TRIMESH_SUFFIXES = (".stl", ".obj", ".ply", ".off", ".glb", ".gltf")
#: File suffixes read through pyvista (VTK XML PolyData and legacy VTK).
VTK_SUFFIXES = (".vtp", ".vtk")
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

    if path.suffix.lower() == ".vtp":
        from vtkmodules.vtkIOXML import vtkXMLPolyDataReader as Reader
    else:
        from vtkmodules.vtkIOLegacy import vtkDataSetReader as Reader
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
        raise MeshError(f"{path}: cannot read mesh: {exc}") from None
    finally:
        vtkOutputWindow.SetInstance(previous)
    errors = _vtk_errors(buffer.GetOutput())
    if errors or output is None:
        reason = errors[0] if errors else "the VTK reader produced nothing"
        raise MeshError(f"{path}: cannot read mesh (corrupt or not a {path.suffix} file): "
                        f"{reason}")
    return pv.wrap(output)


def _vtk_errors(text: str) -> list[str]:
    """The messages of VTK's ``ERROR: In file, line N`` / ``vtkClass (0x...): message`` blocks."""
    out = []
    lines = text.splitlines()
    for k, line in enumerate(lines):
        if line.startswith("ERROR") and k + 1 < len(lines):
            message = lines[k + 1]
            out.append(message.split("): ", 1)[1].strip() if "): " in message else message.strip())
    return out


def _read_vtk(path: Path):
    """(vertices, faces) of a .vtp/.vtk file, triangulated; pyvista imported only here."""
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
                            f"({type(data).__name__}): {exc}") from None
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
        VTK ``.vtp`` / ``.vtk`` file (read with pyvista, imported only for these; polygons
        are triangulated, and a volume mesh is reduced to its outer surface).
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
        raise SceneFileNotFoundError(f"{path}: mesh file not found")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise MeshError(f"{path}: unsupported mesh format {path.suffix!r} "
                        f"(use one of {', '.join(MESH_SUFFIXES)})")
    if path.suffix.lower() in VTK_SUFFIXES:
        vertices, faces = _read_vtk(path)
    else:
        try:
            loaded = trimesh.load(path, force="mesh", process=False)
        except Exception as exc:  # trimesh raises many types on corrupt files
            raise MeshError(f"{path}: cannot read mesh: {exc}") from None
        vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
        faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if len(faces) == 0 or len(vertices) == 0:
        raise MeshError(f"{path}: mesh is empty (no triangles)")
    if not np.all(np.isfinite(vertices)):
        bad = int(np.sum(~np.all(np.isfinite(vertices), axis=1)))
        raise MeshError(f"{path}: {bad} vertices are NaN or infinite")
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=bool(process),
                           validate=False)
    return mesh
