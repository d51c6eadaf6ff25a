"""CIL's AcquisitionGeometry of a scan (``xray_viz.scan.cil_geometry``), checked against CIL's
own conventions: CIL is not on PyPI, so its ASTRA plugin's conversion
(``cil/plugins/astra/utilities/convert_geometry_to_astra_vec_3D.py``: the system in CIL's
frame, rotation axis along z through the origin; projection ``i`` turns source, detector and
the panel's row and column vectors by ``Rz(-initial_angle - angle_i)``; a ``top`` origin
negates the column vector) is written out here and must give the ASTRA vectors that
``astra_vectors`` gives for the same scan (themselves tested against projections)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import xray_viz
from xray_viz.errors import SceneError
from xray_viz.scan import Orbit, astra_vectors, cil_geometry, scan_geometry, to_cil


def _cil_to_astra(g) -> np.ndarray:
    """CIL's ASTRA conversion of :func:`cil_geometry`'s arguments, in the scene's frame."""
    c = g["create"]
    axis = np.asarray(c["rotation_axis_direction"], float)
    z = axis / np.linalg.norm(axis)
    x = np.cross([0.0, 0.0, 1.0] if abs(z[2]) < 0.9 else [1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    frame = np.stack([x, np.cross(z, x), z])      # rows: CIL's x, y, z in the scene's frame
    origin = np.asarray(c["rotation_axis_position"], float)

    def to_cil_frame(p):
        return frame @ (np.asarray(p, float) - origin)

    pu, pv = g["panel"]["pixel_size"]
    row = pu * frame @ np.asarray(c["detector_direction_x"], float)
    col = pv * frame @ np.asarray(c["detector_direction_y"], float)
    if "right" in g["panel"]["origin"]:
        row = -row
    if "top" in g["panel"]["origin"]:
        col = -col
    det = to_cil_frame(c["detector_position"])
    src = (to_cil_frame(c["source_position"]) if g["beam"] == "cone"
           else frame @ np.asarray(c["ray_direction"], float))
    out = []
    for angle in g["angles"]:
        turn = Rotation.from_euler("z", -angle, degrees=True).as_matrix()   # CIL's Rz(-angle)
        back = frame.T @ turn
        first = back @ src + (origin if g["beam"] == "cone" else 0.0)
        out.append(np.concatenate([first, back @ det + origin, back @ row, back @ col]))
    return np.asarray(out)


@pytest.mark.parametrize("axis, center, parallel", [
    ([0, 1, 0], [0, 0, 0], False),
    ([0.2, 0.9, -0.3], [5.0, -3.0, 12.0], False),
    ([1, 0, 0], [0, 0, 0], True),
])
def test_cil_geometry_gives_astras_vectors_as_cils_plugin_reads_it(axis, center, parallel):
    scene = xray_viz.load_scene("sphere")
    if parallel:
        scene = scene.replace(source=dataclasses.replace(scene.source, kind="parallel"))
        assert scene.acquisition.parallel
    geometry = scan_geometry(scene, Orbit(projections=7, arc=250.0, axis=axis, center=center))
    g = cil_geometry(geometry)
    assert g["beam"] == ("parallel" if parallel else "cone")
    assert g["panel"] == {"num_pixels": [256, 256], "pixel_size": [0.5, 0.5], "origin": "top-left"}
    np.testing.assert_allclose(_cil_to_astra(g), astra_vectors(geometry), atol=1e-9)


def test_cil_geometry_refuses_what_cil_cannot_hold():
    scene = xray_viz.load_scene("sphere")
    helical = scan_geometry(scene, Orbit("helical", projections=4, axis=[0, 1, 0], pitch=10.0))
    with pytest.raises(SceneError, match="helical"):
        cil_geometry(helical)
    try:
        import cil  # noqa: F401
    except ImportError:
        with pytest.raises(SceneError, match="CIL is not installed"):
            to_cil(scan_geometry(scene, Orbit(projections=2, axis=[0, 1, 0])))
