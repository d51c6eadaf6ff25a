"""TIGRE geometry export and import (issue 14): every pixel where TIGRE's projector puts it
(its Siddon kernel's formulas, Common/CUDA/Siddon_projection.cu), and the poses come back."""

from __future__ import annotations

import dataclasses
import importlib

import numpy as np
import pytest

import xray_viz
from xray_viz.errors import SceneError
from xray_viz.orbit import Orbit, orbit_from_dict

S = importlib.import_module("xray_viz.scan")


def _euler_zyz(alpha, theta, psi, p):
    """TIGRE's eulerZYZ, as written in its CUDA source."""
    ca, sa, ct, st, cp, sp = (np.cos(alpha), np.sin(alpha), np.cos(theta), np.sin(theta),
                              np.cos(psi), np.sin(psi))
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    return np.stack([(ca * ct * cp - sa * sp) * x + (-ca * ct * sp - sa * cp) * y + ca * st * z,
                     (sa * ct * cp + ca * sp) * x + (-sa * ct * sp + ca * cp) * y + sa * st * z,
                     -st * cp * x + st * sp * y + ct * z], axis=-1)


def _tigre_pixels(t, k):
    """Scene positions of TIGRE's detector pixels (V row, U column) and source, projection k."""
    nv, nu = t["nDetector"]
    dv, du = t["dDetector"]
    off_v, off_u = t["offDetector"][k]
    rows, cols = np.meshgrid(np.arange(nv), np.arange(nu), indexing="ij")
    P = np.stack([np.full(rows.shape, -(t["DSD"][k] - t["DSO"][k])),
                  du * (cols - nu / 2 + 0.5) + off_u, dv * (nv / 2 - 0.5 - rows) + off_v], -1)
    a = t["angles"][k]
    o = np.asarray(t["offOrigin"][k])[::-1]                 # (z, y, x) -> (x, y, z)
    P = _euler_zyz(*a, P) - o
    src = _euler_zyz(*a, np.array([t["DSO"][k], 0.0, 0.0])) - o
    M, origin = np.asarray(t["frame"]["axes"]), np.asarray(t["frame"]["origin"])
    return origin + P @ M, origin + M.T @ src


@pytest.mark.parametrize("orbit", [
    Orbit(projections=5, arc=200.0, axis=[0.3, 1.0, 0.0], center=[3.0, -2.0, 1.0], start=17.0),
    Orbit("helical", projections=6, arc=720.0, axis=[0.0, 1.0, 0.0], pitch=25.0)],
    ids=["circular", "helical"])
def test_tigre_geometry_puts_every_pixel_where_the_rays_end(orbit):
    scene = xray_viz.load_scene("sphere")
    scene = scene.replace(detector=dataclasses.replace(scene.detector, shape=(7, 5),
                                                       pitch=(3.0, 2.0), up=orbit.axis))
    g = S.scan_geometry(scene, orbit)
    t = S.tigre_geometry(g)
    assert t["nDetector"].tolist() == [5, 7] and t["dDetector"].tolist() == [2.0, 3.0]
    assert np.allclose(t["DSD"], 1500.0)
    # DSO: from the source to the axis along the beam (the centre's sideways offset is the
    # volume's, in offOrigin)
    src, det = np.array(g["poses"][0]["source"]), np.array(g["poses"][0]["detector_center"])
    beam = (det - src) / np.linalg.norm(det - src)
    np.testing.assert_allclose(t["DSO"], (orbit.center - src) @ beam, rtol=1e-12)
    for k, acq in enumerate(orbit.acquisitions(scene.acquisition)):
        pixels, src = _tigre_pixels(t, k)
        np.testing.assert_allclose(pixels, acq.rays().ends.reshape(5, 7, 3), rtol=0, atol=1e-9)
        np.testing.assert_allclose(src, acq.frame.source, rtol=0, atol=1e-9)
    steps = np.diff(np.unwrap(t["angles"][:, 0]))
    np.testing.assert_allclose(steps, np.radians(orbit.arc / orbit.projections), atol=1e-12)
    if orbit.kind == "helical":                       # the volume moves along TIGRE's z
        np.testing.assert_allclose(t["offOrigin"][:, 0], -25.0 * orbit.angles() / 360.0,
                                   atol=1e-9)
    for a, b in zip(S.poses_from_tigre(t), g["poses"]):          # and back
        for key in ("source", "detector_center", "u", "v"):
            np.testing.assert_allclose(a[key], b[key], rtol=0, atol=1e-9)


def test_poses_to_tigre_to_poses_for_a_circular_orbit_and_refusals():
    scene = xray_viz.load_scene("sphere")
    circ = S.scan_geometry(scene, Orbit(projections=12, axis=[0, 1, 0]))
    poses_orbit = Orbit("poses", poses=circ["poses"])
    g = S.scan_geometry(scene, poses_orbit)
    with pytest.raises(SceneError, match="give tigre_geometry"):
        S.tigre_geometry(g)
    t = S.tigre_geometry(g, axis=[0, 1, 0], center=[0, 0, 0])
    np.testing.assert_allclose(t["angles"][:, 0], np.radians(30.0 * np.arange(12)), atol=1e-12)
    assert np.allclose(t["offOrigin"], 0, atol=1e-9) and np.allclose(t["offDetector"], 0,
                                                                      atol=1e-9)
    back = Orbit("poses", poses=S.poses_from_tigre(t))
    again = S.scan_geometry(scene, back)
    np.testing.assert_allclose(again["projection_matrices"], circ["projection_matrices"],
                               atol=1e-9)
    tilted = orbit_from_dict({"axis": [0, 1, 0], "poses": {"random": 3, "tilt": [5.0, 9.0]}})
    with pytest.raises(SceneError, match="pose 0: the detector is tilted"):
        S.tigre_geometry(S.scan_geometry(scene, tilted), axis=[0, 1, 0], center=[0, 0, 0])
    with pytest.raises(SceneError, match="theta/psi"):
        S.poses_from_tigre({**t, "angles": t["angles"] + [0.0, 0.1, 0.0]})
