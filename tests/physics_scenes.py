"""Small scenes for the physics tests, written to a temporary directory."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import trimesh

import xray_viz


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float, np.integer, np.floating)):
        return repr(float(value)) if isinstance(value, (float, np.floating)) else str(int(value))
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{json.dumps(str(k))} = {_toml_value(v)}"
                                for k, v in value.items()) + " }"
    return "[" + ", ".join(_toml_value(v) for v in value) + "]"


def write_scene(tmp_path: Path, *, source: dict, detector: dict, bodies=(), name="scene"):
    """Write meshes and a TOML scene; ``bodies`` are ``(name, trimesh, {key: value})``."""
    lines = ["[source]"] + [f"{k} = {_toml_value(v)}" for k, v in source.items()]
    lines += ["", "[detector]"] + [f"{k} = {_toml_value(v)}" for k, v in detector.items()]
    for body_name, mesh, keys in bodies:
        mesh_file = f"{name}_{body_name}.stl"
        mesh.export(tmp_path / mesh_file)
        lines += ["", "[[body]]", f"name = {json.dumps(body_name)}",
                  f"mesh = {json.dumps(mesh_file)}"]
        lines += [f"{k} = {_toml_value(v)}" for k, v in keys.items()]
    path = tmp_path / f"{name}.toml"
    path.write_text("\n".join(lines) + "\n")
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
