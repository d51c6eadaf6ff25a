"""Reading triangle meshes from files."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from xray_viz.errors import MeshError, SceneFileNotFoundError

__all__ = ["load_mesh", "MESH_SUFFIXES"]

#: File suffixes read by :func:`load_mesh` (through trimesh).
MESH_SUFFIXES = (".stl", ".obj", ".ply", ".off", ".glb", ".gltf")


def load_mesh(path: str | Path):
    """Read a triangle mesh and check that it can be traced.

    Parameters
    ----------
    path : str or Path
        An STL (ASCII or binary), OBJ, PLY, OFF or GLB/GLTF file.

    Returns
    -------
    trimesh.Trimesh
        Duplicate vertices merged (STL is a triangle soup).

    Raises
    ------
    SceneFileNotFoundError
        The file does not exist.
    MeshError
        The file cannot be read, holds no triangles, or has NaN or infinite vertices.
    """
    import trimesh

    path = Path(path)
    if not path.exists():
        raise SceneFileNotFoundError(f"{path}: mesh file not found")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise MeshError(f"{path}: unsupported mesh format {path.suffix!r} "
                        f"(use one of {', '.join(MESH_SUFFIXES)})")
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
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=True, validate=False)
    return mesh
