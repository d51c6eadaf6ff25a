"""A starting point: a scene framed around one mesh file, with a stated material.

``xray-viz render part.stl`` renders a mesh file without a scene file (:func:`framed_document`,
read by :func:`xray_viz.load_scene`), and ``xray-viz init --from part.stl`` writes the same scene
as a commented file to edit (:func:`scene_text`). The framing: the beam runs along -z, the source
on the axis through the centre of the mesh's bounding box at :func:`framing`'s distance, the
detector beyond it, with the pitch that fits the shadow of the bounding sphere with a 10 % margin
on a 512 x 512 detector. The mesh's units are taken as mm; the material is :data:`MATERIAL`
(aluminium, as in industrial CT) at :data:`ENERGY` keV.

Examples
--------
>>> import numpy as np
>>> f = framing(np.array([[-10.0, -10.0, -10.0], [10.0, 10.0, 10.0]]))
>>> f["source"], f["detector_center"], f["shape"]
([0.0, 0.0, 1000.0], [0.0, 0.0, -500.0], [512, 512])
"""

from __future__ import annotations

import json
import logging
import math
import os
from pathlib import Path

import numpy as np

__all__ = ["MATERIAL", "DENSITY", "ENERGY", "SHAPE", "FILL", "is_mesh_file", "framing",
           "framed_document", "scene_text", "describe"]

log = logging.getLogger("xray_viz.starter")

#: The material a mesh is given when no scene file says which (an element: its density below).
MATERIAL = "Al"
#: Its density, g/cm3 (aluminium, NIST).
DENSITY = 2.699
#: The monochromatic energy, keV.
ENERGY = 60.0
#: The detector's pixels, [W, H].
SHAPE = (512, 512)
#: The shadow of the bounding sphere fills this fraction of the detector's half-width.
FILL = 1 / 1.1


def is_mesh_file(path) -> bool:
    """Whether ``path`` names a mesh file that :func:`xray_viz.meshes.io.load_mesh` reads (by
    its suffix; ``model.glb#NODE`` too)."""
    from xray_viz.meshes.io import MESH_SUFFIXES

    return str(path).split("#", 1)[0].lower().endswith(MESH_SUFFIXES)


def _round_up(x: float, digits: int = 3) -> float:
    """``x`` rounded up to ``digits`` significant figures."""
    scale = 10.0 ** (math.floor(math.log10(x)) - digits + 1)
    return math.ceil(x / scale - 1e-9) * scale


def framing(bounds) -> dict:
    """The source and detector framed around a body's axis-aligned ``bounds`` (2, 3), mm.

    The source is on the +z side of the centre ``c`` of the bounds, at SOD = max(1000 mm,
    4 r) from it (``r`` half the box's diagonal, so the source is well outside), the detector
    centre at SID = 1.5 SOD from the source, and the pitch makes the cone tangent to the
    sphere of radius ``r`` about ``c`` meet the detector at :data:`FILL` of its half-width.

    Returns
    -------
    dict
        ``source``, ``detector_center`` (lists, mm), ``shape`` ([W, H]), ``pitch`` (mm),
        ``sod``, ``sid`` (mm) and ``radius`` (mm).
    """
    bounds = np.asarray(bounds, dtype=np.float64)
    c = bounds.mean(axis=0)
    r = max(0.5 * float(np.linalg.norm(bounds[1] - bounds[0])), 1e-3)
    sod = max(1000.0, 10.0 * math.ceil(0.4 * r))
    sid = 1.5 * sod
    half = r * sid / math.sqrt(sod * sod - r * r) / FILL
    pitch = _round_up(2.0 * half / SHAPE[0])

    def point(z):
        return [round(float(c[0]), 4), round(float(c[1]), 4), round(float(c[2] + z), 4)]

    return {"source": point(sod), "detector_center": point(sod - sid), "shape": list(SHAPE),
            "pitch": pitch, "sod": sod, "sid": sid, "radius": r}


def _document(mesh_path: Path, mesh_text: str) -> tuple[dict, dict]:
    from xray_viz.meshes.io import load_mesh

    mesh = load_mesh(mesh_path)
    f = framing(mesh.bounds)
    name = Path(str(mesh_path).split("#", 1)[0]).stem or "part"
    doc = {"source": {"position": f["source"], "kind": "point", "energy": ENERGY},
           "detector": {"center": f["detector_center"], "up": [0.0, 1.0, 0.0],
                        "shape": f["shape"], "pitch": f["pitch"]},
           "body": [{"name": name, "mesh": mesh_text, "material": MATERIAL,
                     "density": DENSITY}]}
    return doc, f


def describe(doc: dict) -> str:
    """One line saying what a framed scene document chose (material, beam, detector)."""
    body, det = doc["body"][0], doc["detector"]
    w, h = det["shape"]
    return (f"material {body['material']} (aluminium, {body['density']} g/cm3; the mesh in "
            f"mm), detector {w}x{h} at {det['pitch']:g} mm framed around it")


def framed_document(mesh_path) -> dict:
    """The scene document of ``mesh_path`` alone, framed (see the module), mesh path relative
    to the mesh's folder; says on the ``xray_viz.starter`` logger what it chose.

    Raises
    ------
    SceneFileNotFoundError, MeshError
        From :func:`xray_viz.meshes.io.load_mesh`.
    """
    p = Path(mesh_path)
    doc, _ = _document(p, p.name)
    log.info("%s: no scene file, so %s (`xray-viz init --from %s` writes this scene to edit)",
             p, describe(doc), p)
    return doc


def _toml(value) -> str:
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)     # a TOML basic string
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return repr(float(value)) if isinstance(value, float) else str(value)


def scene_text(mesh_path, *, relative_to=None, name: str = "scene.toml") -> str:
    """A commented scene file framed around ``mesh_path`` (see the module), to edit.

    Parameters
    ----------
    mesh_path : path-like
        The mesh file (any suffix :func:`is_mesh_file` accepts).
    relative_to : path-like, optional
        The folder the scene file will be in: the mesh path is written relative to it where
        possible (absolute on another drive); default: absolute.
    name : str
        The scene file's name, in the comment that says how to render it.

    Returns
    -------
    str
        TOML text; :func:`xray_viz.load_scene` of it, written in ``relative_to``, is the scene
        :func:`framed_document` describes.
    """
    p = Path(mesh_path)
    text = str(p.resolve())
    if relative_to is not None:
        try:
            text = Path(os.path.relpath(p.resolve(), Path(relative_to).resolve())).as_posix()
        except ValueError:                 # another drive
            pass
    doc, f = _document(p, text)
    s, d, b = doc["source"], doc["detector"], doc["body"][0]
    rows = [
        f"# A scene framed around {p.name} by `xray-viz init`. Edit it, then:",
        f"#   xray-viz render {name} -o image.png      (xray-viz show {name}: the 3D view)",
        "# Geometry in mm, mu in 1/cm, energies in keV; every key is in the README, \"Scene files\".",
        "", "[source]",
        (f"position = {_toml(s['position'])}", f"mm: {f['sod']:g} mm above the mesh's centre (+z)"),
        ('kind = "point"', 'or "parallel": every ray along position -> detector centre'),
        (f"energy = {_toml(s['energy'])}", "keV, monochromatic; or spectrum = { kvp = 80.0 }"),
        "", "[detector]",
        (f"center = {_toml(d['center'])}",
         f"mm: the beam axis runs source -> centre (SID {f['sid']:g} mm)"),
        ("up = [0.0, 1.0, 0.0]", "the image's up direction"),
        (f"shape = {_toml(d['shape'])}", "pixels [W, H]"),
        (f"pitch = {_toml(d['pitch'])}", "mm between pixels: the mesh's shadow fits, with a margin"),
        "", "[[body]]",
        f"name = {_toml(b['name'])}",
        (f"mesh = {_toml(b['mesh'])}", 'relative to this file; read in mm (else units = "cm", ...)'),
        (f"material = {_toml(b['material'])}",
         'aluminium; or a NIST name ("Water, Liquid"), a formula,'),
        (f"density = {_toml(b['density'])}", "g/cm3  ... or mu = 0.2 (1/cm) instead of both"),
    ]
    return "".join((row if isinstance(row, str) else f"{row[0]:<31} # {row[1]}") + "\n"
                   for row in rows)
