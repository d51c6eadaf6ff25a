"""Small scenes for the physics tests, written to a temporary directory."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import tomlkit
import trimesh

import xray_viz


def _plain(value):
    """NumPy numbers and arrays as the Python values a TOML writer takes."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def write_scene(tmp_path: Path, *, source: dict, detector: dict, bodies=(), name="scene"):
    """Write meshes and a TOML scene (tomlkit); ``bodies`` are ``(name, trimesh, {key: value})``."""
    doc = {"source": _plain(source), "detector": _plain(detector)}
    entries = []
    for body_name, mesh, keys in bodies:
        mesh_file = f"{name}_{body_name}.stl"
        mesh.export(tmp_path / mesh_file)
        entries.append({"name": body_name, "mesh": mesh_file, **_plain(keys)})
    if entries:
        doc["body"] = entries
    path = tmp_path / f"{name}.toml"
    path.write_text(tomlkit.dumps(doc))
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
