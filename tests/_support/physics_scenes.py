"""Small scenes for the physics tests, written to a temporary directory."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

import xray_viz
from xray_viz._toml import dumps, plain as _plain


def write_scene(tmp_path: Path, *, source: dict, detector: dict, bodies=(), name="scene"):
    """Write meshes and a TOML scene (xray_viz's TOML writer); ``bodies`` are ``(name, trimesh, {key: value})``."""
    doc = {"source": _plain(source), "detector": _plain(detector)}
    entries = []
    for body_name, mesh, keys in bodies:
        mesh_file = f"{name}_{body_name}.stl"
        mesh.export(tmp_path / mesh_file)
        entries.append({"name": body_name, "mesh": mesh_file, **_plain(keys)})
    if entries:
        doc["body"] = entries
    path = tmp_path / f"{name}.toml"
    path.write_text(dumps(doc))
    return path


def parallel_detector(shape=(8, 8), pitch=1.0, **extra):
    return {"center": [0.0, 0.0, -500.0], "up": [0.0, 1.0, 0.0], "shape": list(shape),
            "pitch": pitch, **extra}


def load(tmp_path, **kw):
    return xray_viz.load_scene(write_scene(tmp_path, **kw))


def box(extents, *, center=(0.0, 0.0, 0.0), angle_z=0.0):
    mesh = trimesh.creation.box(extents=extents)
    if angle_z:
        mesh.apply_transform(trimesh.transformations.rotation_matrix(np.radians(angle_z),
                                                                     [0, 0, 1]))
    mesh.apply_translation(center)
    return mesh


def pixel_centres(shape, pitch):
    """(H, W) x and y (mm) of the pixel rays of a detector centred on the z axis, up = +y."""
    w, h = shape
    x = (np.arange(w) - (w - 1) / 2) * pitch
    y = ((h - 1) / 2 - np.arange(h)) * pitch
    return np.meshgrid(x, y)
