"""Meshes: reading, checking, repairing and decimating the bodies' triangle surfaces.

Nothing here imports VTK or pyvista at import time (only :func:`load_mesh` does, for .vtp/.vtk
files), and pymeshlab is imported only when a repair or decimation runs.

Examples
--------
>>> import trimesh
>>> from xray_viz.meshes import check_mesh, repair_mesh, decimate
>>> ball = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
>>> check_mesh(ball).traceable
True
"""

from xray_viz.meshes.decimate import decimate, hausdorff_distance
from xray_viz.meshes.io import MESH_SUFFIXES, load_mesh
from xray_viz.meshes.repair import (
    MeshRepairWarning,
    MeshReport,
    RepairReport,
    check_mesh,
    ensure_traceable,
    repair_mesh,
)

__all__ = [
    "load_mesh", "MESH_SUFFIXES", "check_mesh", "repair_mesh", "ensure_traceable", "decimate",
    "hausdorff_distance", "MeshReport", "RepairReport", "MeshRepairWarning",
]
