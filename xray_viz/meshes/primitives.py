"""Primitive shapes as bodies: ``[[body]] shape = { kind = "box", size = [x, y, z] }``.

A shape is a closed triangle mesh made by trimesh, centred on the origin (its bounding box's
centre) before the body's ``position``, ``rotation``, ``scale`` and ``units`` place it, as a
mesh file's coordinates would be:

==============  =================================  =========================================
``kind``        keys (mm)                          mesh
==============  =================================  =========================================
``"box"``       ``size = [x, y, z]``               12 triangles, exact
``"sphere"``    ``radius``, ``subdivisions`` (4)   icosphere: vertices on the sphere
``"cylinder"``  ``radius``, ``height``,            axis along z; ``sections`` vertices on each
                ``sections`` (64)                  circle (the polygon inscribed in it)
``"cone"``      ``radius``, ``height``,            axis along z, apex at +height/2
                ``sections`` (64)
==============  =================================  =========================================

Examples
--------
>>> shape = check_shape({"kind": "cylinder", "radius": 5.0, "height": 20.0})
>>> shape
{'kind': 'cylinder', 'radius': 5.0, 'height': 20.0, 'sections': 64}
>>> mesh = shape_mesh(shape)
>>> mesh.is_watertight, mesh.bounds.tolist()
(True, [[-5.0, -5.0, -10.0], [5.0, 5.0, 10.0]])
"""

from __future__ import annotations

import math

import numpy as np

from xray_viz.errors import SceneError

__all__ = ["SHAPES", "check_shape", "shape_mesh"]

#: Each kind: its required keys and its optional keys with their defaults.
SHAPES = {
    "box": (("size",), {}),
    "sphere": (("radius",), {"subdivisions": 4}),
    "cylinder": (("radius", "height"), {"sections": 64}),
    "cone": (("radius", "height"), {"sections": 64}),
}


def _positive(value, what) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or not value > 0:
        raise SceneError(f"{what} must be a number > 0 (mm), got {value!r}")
    return float(value)


def check_shape(value) -> dict:
    """The canonical shape table (every key, defaults filled in), or a one-line SceneError
    naming the key."""
    if not isinstance(value, dict):
        raise SceneError(f"shape must be a table such as {{ kind = \"box\", size = [10.0, 10.0, "
                         f"10.0] }}, got {value!r}")
    kind = value.get("kind")
    if kind not in SHAPES:
        raise SceneError(f"shape kind must be one of {', '.join(SHAPES)}, got {kind!r}")
    required, optional = SHAPES[kind]
    unknown = sorted(set(value) - {"kind", *required, *optional})
    if unknown:
        raise SceneError(f"shape {kind!r}: unknown key {unknown[0]!r}; it takes "
                         f"{', '.join((*required, *optional))}")
    out: dict = {"kind": kind}
    for key in required:
        if key not in value:
            raise SceneError(f"shape {kind!r} needs {key!r}")
        if key == "size":
            size = value[key]
            if not isinstance(size, list) or len(size) != 3:
                raise SceneError(f"shape 'box' size must be [x, y, z] (mm), got {size!r}")
            out[key] = [_positive(s, "shape 'box' size") for s in size]
        else:
            out[key] = _positive(value[key], f"shape {kind!r} {key}")
    for key, default in optional.items():
        n = value.get(key, default)
        low = 0 if key == "subdivisions" else 3
        if isinstance(n, bool) or not isinstance(n, int) or not low <= n <= 4096 \
                or (key == "subdivisions" and n > 7):
            raise SceneError(f"shape {kind!r} {key} must be a whole number from {low} to "
                             f"{7 if key == 'subdivisions' else 4096}, got {n!r}")
        out[key] = n
    return out


def shape_mesh(shape: dict):
    """The closed, outward triangle mesh (trimesh) of a :func:`check_shape` table, centred
    on the origin."""
    import trimesh

    shape = check_shape(shape)
    kind = shape["kind"]
    if kind == "box":
        mesh = trimesh.creation.box(extents=shape["size"])
    elif kind == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=shape["subdivisions"],
                                          radius=shape["radius"])
    elif kind == "cylinder":
        mesh = trimesh.creation.cylinder(radius=shape["radius"], height=shape["height"],
                                         sections=shape["sections"])
    else:
        mesh = trimesh.creation.cone(radius=shape["radius"], height=shape["height"],
                                     sections=shape["sections"])
        mesh.apply_translation([0.0, 0.0, -shape["height"] / 2])
    mesh.vertices = np.asarray(mesh.vertices, dtype=np.float64)
    return mesh
